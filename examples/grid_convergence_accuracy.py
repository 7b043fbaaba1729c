"""Track error of the engine on the demo survey on and 200 km off the UTM central meridian.

The demo design lies on the central meridian of UTM zone 50N (E 500 km, 28 deg N). Moved 200 km
east, its site has 0.96 deg of grid convergence and a point scale of 1.00009. The truth simulator
puts the IMU in true north and the odometer on the ground while the design and the fixes stay in
the grid (trolley/truthsim.py, ``SimulationConfig.crs``); the engine turns the grid into true
north with the CRS in session.toml (trolley/projection.py). Four cases, same seed:

- on the meridian, CRS given;
- 200 km off, CRS given;
- 200 km off, no CRS in session.toml (the engine refuses: most fixes rejected, a consistent
  rotation);
- 200 km off, no CRS, and the check that refuses it switched off: what the engine did before.

Run from the repository root:  python examples/grid_convergence_accuracy.py [--length-m 1200] [--seed 0]
"""
from __future__ import annotations

import argparse
from pathlib import Path
from unittest import mock

import numpy as np

from survey.commands.simulate import project_settings
from trolley import engine
from trolley.landxml import parse_landxml
from trolley.sensors import IMU_PRESETS
from trolley.truthsim import SimulationConfig, simulate_survey
from trolley.validation import track_errors

DEMO = Path(__file__).resolve().parents[1] / "projects" / "demo"
CRS = "EPSG:32650"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--length-m", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--east-m", type=float, default=200000.0)
    args = ap.parse_args()
    kwargs, preset, xml = project_settings(DEMO)
    kwargs.update(imu=IMU_PRESETS[preset], length_m=args.length_m, seed=args.seed, crs=CRS)
    design = parse_landxml(xml)
    cases = [("on the meridian, CRS given", 0.0, True, True),
             (f"{args.east_m / 1e3:g} km off, CRS given", args.east_m, True, True),
             (f"{args.east_m / 1e3:g} km off, no CRS", args.east_m, False, True),
             (f"{args.east_m / 1e3:g} km off, no CRS, no refusal (before)", args.east_m, False, False)]
    for name, east, crs_in, check in cases:
        d = design.translated(east, 0.0)
        sim = simulate_survey(d, SimulationConfig(**kwargs, crs_in_session=crs_in))
        g = sim.truth.geometry.grid
        head = (f"{name}: convergence {np.rad2deg(g.convergence_rad):+.4f} deg, point scale {g.point_scale:.9f}, "
                f"combined scale {g.combined_scale:.9f}")
        try:
            with mock.patch.object(engine, "check_rotation", engine.check_rotation if check else lambda *a: None):
                res = engine.process_session(sim.session, d, with_observability=False)
        except ValueError as exc:
            print(f"{head}\n  refused: {exc}")
            continue
        tj = res.trajectory
        e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth, cov_EN_m2=tj.cov_EN_m2)
        rms = [1e3 * x for x in e.rms_m()]
        worst = [1e3 * float(np.max(np.abs(x))) for x in (e.lateral_m, e.longitudinal_m, e.vertical_m)]
        q = e.normalised_rms()
        print(f"{head}\n  fixes used/rejected {res.summary['fixes_used']}/{res.summary['fixes_rejected']}; "
              f"error lateral/longitudinal/vertical RMS {rms[0]:.3f}/{rms[1]:.3f}/{rms[2]:.3f} mm, "
              f"max {worst[0]:.3f}/{worst[1]:.3f}/{worst[2]:.3f} mm; RMS(error/sigma) {q[0]:.2f}/{q[1]:.2f}/{q[2]:.2f}")


if __name__ == "__main__":
    main()
