"""Track Geometry Measuring System (TGMS): track irregularities from laser-line cameras, an IMU and
an encoder, after Escalona 2021, Gonzalez-Carbajal 2023 and Briales (track-frame kinematics).

Frames: every body frame here is FRD (x forward, y right, z down); the track frame (TF) is also
taken FRD, i.e. the paper's track frame (y left, z up) turned 180 deg about x. The paper's vector
equations (Eq. 4-5, 14, 36, 44-46) keep their form in this frame because it is a proper rotation of
the paper's; the curvatures then carry FRD signs (rho_h > 0 right turn, rho_v > 0 nose-up rate,
cant > 0 left rail higher). Conversion to the published irregularity signs happens once, in
``irregularities``.

Modules: ``profiles`` (60E1/54E1 rail heads), ``camera`` (pin-hole + laser plane, Eq. 17-19),
``vision`` (robust batch profile fit, Sec. 5), ``track`` (track preprocessor, Sec. 3.2),
``odometry`` (Eq. 40-43), ``orientation`` (Eq. 38-39, Briales Eq. 18), ``trajectory`` (Eq. 46),
``irregularities`` (Eq. 24, 27), ``simulate`` (synthetic recordings), ``config`` (dataclasses).
"""
