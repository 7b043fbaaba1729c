"""TGMS vision: camera model (Escalona 2021 Eq. 17-19), rail-head profiles and the batch fit."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from trolley.tgms.camera import Camera, check_camera, pixels_to_tgms, project
from trolley.tgms.profiles import GAUGE_POINT_DEPTH_M, rail_profile
from trolley.tgms.simulate import default_cameras
from trolley.tgms.vision import fit_rail

CAMS = default_cameras()


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.05, 0.05), st.floats(-0.03, 0.03), st.sampled_from(["left", "right"]))
def test_pixel_to_laser_plane_inverts_projection(dy, dz, side):
    cam = CAMS[side]
    sgn = -1 if side == "left" else 1
    p = np.array([[0.0, sgn * 0.73 + dy, 0.46 + dz]])          # on the laser plane x = 0
    u, v, depth = project(cam, p)
    assert depth[0] > 0
    back = pixels_to_tgms(cam, u, v)
    assert np.allclose(back, p, atol=1e-9)


def test_oblique_laser_plane_and_distortion_round_trip():
    cam = CAMS["right"]
    plane = np.array([1.0, 0.05, -0.1, 0.02])
    cam2 = Camera(cam.K, cam.R_tgms_cam, cam.t_tgms_cam_m, np.array([-0.2, 0.05, 1e-3, -2e-3]), plane, name="right")
    rng = np.random.default_rng(0)
    y = 0.73 + rng.uniform(-0.05, 0.05, 50)
    z = 0.45 + rng.uniform(-0.03, 0.03, 50)
    x = -(plane[1] * y + plane[2] * z + plane[3]) / plane[0]
    pts = np.column_stack([x, y, z])
    u, v, _ = project(cam2, pts)
    assert np.allclose(pixels_to_tgms(cam2, u, v), pts, atol=1e-8)


def test_camera_whose_laser_plane_is_behind_it_is_rejected():
    cam = CAMS["left"]
    bad = Camera(cam.K, cam.R_tgms_cam, cam.t_tgms_cam_m, cam.distortion, np.array([1.0, 0.0, 0.0, 1.0]), name="left")
    with pytest.raises(ValueError, match="camera left: the laser plane does not meet"):
        check_camera(bad)


def test_laser_plane_seen_only_near_a_corner_is_accepted():
    """The centre ray meets the plane behind the camera, the top-left corner's ray in front: the
    plane does meet the view, so check_camera accepts it (it tests the corners, not only the centre)."""
    cam = CAMS["right"]
    cam0 = Camera(cam.K, cam.R_tgms_cam, cam.t_tgms_cam_m, np.zeros(4), np.array([1.0, 0.0, 0.0, 0.0]), name="right")
    K_inv = np.linalg.inv(np.asarray(cam.K, float))
    R = np.asarray(cam.R_tgms_cam, float)
    ray = lambda u, v: (R @ K_inv @ np.array([u, v, 1.0])) / np.linalg.norm(R @ K_inv @ np.array([u, v, 1.0]))
    w, h = cam.image_size_px
    d_c, d_k = ray(w / 2.0, h / 2.0), ray(0.0, 0.0)
    n = d_k - 1.0 * d_c                     # d_c . d_k < 1 < 1 / (d_c . d_k): n.d_c < 0 < n.d_k
    p0 = np.asarray(cam.t_tgms_cam_m, float) + d_k
    good = Camera(cam0.K, cam0.R_tgms_cam, cam0.t_tgms_cam_m, cam0.distortion, np.append(n, -n @ p0), name="right")
    assert np.isnan(pixels_to_tgms(good, np.array([w / 2.0]), np.array([h / 2.0]))).all()
    assert pixels_to_tgms(good, np.array([0.0]), np.array([0.0]))[0] == pytest.approx(p0, abs=1e-9)
    check_camera(good)


@pytest.mark.parametrize("name,width", [("60E1", 0.072), ("54E1", 0.070)])
def test_head_geometry(name, width):
    p = rail_profile(name, 0.0)        # upright: the head width is measured horizontally
    o = p.outline_m
    assert o[:, 1].min() == pytest.approx(0.0, abs=1e-9)        # origin at the running surface
    band = np.abs(o[:, 1] - GAUGE_POINT_DEPTH_M) < 3e-5
    assert o[band, 0].min() == pytest.approx(0.0, abs=2e-5)        # ... and at the gauge point
    assert o[band, 0].max() - o[band, 0].min() == pytest.approx(width, abs=5e-5)
    d, gy, gz, ok = p.signed_distance(o[o[:, 1] < 0.03, 0], o[o[:, 1] < 0.03, 1])
    assert ok.all() and np.abs(d).max() < 1e-6
    # 2 mm above the crown is 2 mm outside; 5 mm into the head is inside
    crown = o[np.argmin(o[:, 1])]
    assert p.signed_distance(np.array([crown[0]]), np.array([crown[1] - 0.002]))[0][0] == pytest.approx(0.002, abs=1e-6)
    assert p.signed_distance(np.array([crown[0]]), np.array([crown[1] + 0.005]))[0][0] < -0.004


def _clouds(prof, poses, rng, noise=1e-4, outliers=0.03, side="right"):
    o = prof.outline_m
    vis = (o[:, 1] < 0.022) & (o[:, 0] < 0.06)
    q = o[vis][::50]
    fr, Y, Z = [], [], []
    for k, (oy, oz, al) in enumerate(poses):
        c, s = np.cos(al), np.sin(al)
        y = oy + c * q[:, 0] - s * q[:, 1] + rng.normal(0, noise, len(q))
        z = oz + s * q[:, 0] + c * q[:, 1] + rng.normal(0, noise, len(q))
        bad = rng.random(len(q)) < outliers
        y[bad] += rng.uniform(-0.01, 0.01, bad.sum())
        z[bad] += rng.uniform(-0.01, 0.01, bad.sum())
        fr.append(np.full(len(q), k)); Y.append(y); Z.append(z)
    Y = np.concatenate(Y)
    if side == "left":
        Y = -Y
    return np.concatenate(fr), Y, np.concatenate(Z)


@pytest.mark.parametrize("side", ["left", "right"])
def test_fit_recovers_pose_within_its_sigma_despite_outliers(side):
    prof = rail_profile("60E1", 40.0)
    rng = np.random.default_rng(1)
    n = 300
    poses = np.column_stack([0.7175 + rng.normal(0, 0.004, n), 0.45 + rng.normal(0, 0.003, n), rng.normal(0, 0.005, n)])
    fr, y, z = _clouds(prof, poses, rng, side=side)
    fit = fit_rail(prof, fr, y, z, n, side)
    sgn = -1.0 if side == "left" else 1.0
    assert fit.ok.mean() > 0.98
    ey = (fit.y_m - sgn * poses[:, 0]) / fit.sigma_y_m
    ez = (fit.z_m - poses[:, 1]) / fit.sigma_z_m
    ok = fit.ok
    # normalised errors: about unit spread, no gross failures
    assert 0.6 < np.std(ey[ok]) < 1.6 and 0.6 < np.std(ez[ok]) < 1.6
    assert np.abs(fit.y_m - sgn * poses[:, 0])[ok].max() < 2e-4
    assert np.abs(fit.angle_rad - sgn * poses[:, 2])[ok].max() < 0.01


def test_frames_without_gauge_face_or_points_are_flagged_not_guessed():
    prof = rail_profile("54E1", 40.0)
    rng = np.random.default_rng(2)
    poses = [(0.7175, 0.45, 0.0)] * 3
    fr, y, z = _clouds(prof, poses, rng, outliers=0.0)
    # frame 1: keep only the crown (no gauge face -> lateral position undetermined)
    keep = ~((fr == 1) & (z > 0.45 + 0.004))
    # frame 3 has no point at all
    fit = fit_rail(prof, fr[keep], y[keep], z[keep], 4, "right")
    assert fit.ok.tolist() == [True, False, True, False]
    assert np.isnan(fit.y_m[1]) and np.isnan(fit.y_m[3])


def test_frame_of_outliers_only_is_flagged():
    """A frame whose points are all reflections (uniform over the view, no rail outline) is flagged,
    while a normal frame next to it is not."""
    prof = rail_profile("60E1", 40.0)
    rng = np.random.default_rng(7)
    fr, y, z = _clouds(prof, [(0.7175, 0.45, 0.0)], rng, outliers=0.0)
    n_out = 200
    y_o = rng.uniform(0.66, 0.78, n_out)
    z_o = rng.uniform(0.43, 0.50, n_out)
    fit = fit_rail(prof, np.concatenate([fr, np.ones(n_out, int)]), np.concatenate([y, y_o]),
                   np.concatenate([z, z_o]), 2, "right")
    assert fit.ok.tolist() == [True, False]
    assert np.isnan(fit.y_m[1]) and np.isnan(fit.z_m[1])


def test_camera_matrix_with_misplaced_entries_is_rejected():
    """(bug hunt) K written transposed, cx and cy in the last row, was accepted: 98 % of the frames
    were flagged and the exit code was 0."""
    cam = CAMS["left"]
    bad = Camera(np.asarray(cam.K, float).T, cam.R_tgms_cam, cam.t_tgms_cam_m, cam.distortion, cam.laser_plane,
                 name="left")
    with pytest.raises(ValueError, match=r"camera left: K must be \[\[fx,0,cx\],\[0,fy,cy\],\[0,0,1\]\]"):
        check_camera(bad)
    check_camera(cam)


def test_laser_plane_through_the_camera_centre_is_named_as_such():
    cam = CAMS["right"]
    x = float(cam.t_tgms_cam_m[0])
    bad = Camera(cam.K, cam.R_tgms_cam, cam.t_tgms_cam_m, cam.distortion, np.array([1.0, 0.0, 0.0, -x]), name="right")
    with pytest.raises(ValueError, match="camera right: the laser plane passes through the camera centre"):
        check_camera(bad)
