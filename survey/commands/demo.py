"""``trolley demo``: the whole chain on the sample project, in one command.

Simulates a stop-and-go survey of ``projects/demo`` with the full 3-D truth simulator, writes the
raw session folder, processes it (dead reckoning, filtering, RTS smoothing), writes the Excel
survey sheet and the plots, compares the track with the simulator's truth, and prints where
everything is.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console

_REPO_DEMO = Path(__file__).resolve().parents[2] / "projects" / "demo"


def demo(
    out: Annotated[Optional[Path], typer.Option("--out", help="output folder (default: projects/demo/out)")] = None,
    imu: Annotated[Optional[str], typer.Option(help="IMU grade: rlg, fog or mems (default: the project's)")] = None,
    seed: Annotated[Optional[int], typer.Option(help="random seed of the simulation")] = None,
) -> None:
    """Simulate, process and export a survey of the demo project; print where the results are."""
    from dataclasses import replace

    import numpy as np

    from survey.commands.engine import fail, print_summary, run_process
    from survey.commands.simulate import ProjectFileError, project_settings
    from survey.export import export_outputs
    from survey.sessionio import write_session, write_truth_csv
    from trolley.landxml import parse_landxml
    from trolley.sensors import IMU_PRESETS
    from trolley.truthsim import SimulationConfig, simulate_survey
    from trolley.validation import track_errors

    con = Console()
    err = Console(stderr=True)
    t_start = time.perf_counter()
    project = Path("projects/demo")
    if not (project / "project.toml").exists():
        project = _REPO_DEMO
    out = out if out is not None else project / "out"
    try:
        kwargs, preset, xml = project_settings(project)
    except ProjectFileError as exc:
        fail(str(exc))
    preset = imu or preset
    if preset not in IMU_PRESETS:
        fail(f"--imu: unknown IMU preset {preset!r} (choose {', '.join(IMU_PRESETS)})")
    kwargs["imu"] = IMU_PRESETS[preset]
    if seed is not None:
        kwargs["seed"] = seed
    design = parse_landxml(xml)
    config = SimulationConfig(**kwargs)
    err.print(f"1/4 simulating {config.length_m:g} m of {project.resolve().name} with the {preset} IMU "
              f"at {config.imu_rate_hz:g} Hz ...", highlight=False)
    sim = simulate_survey(design, config)
    session_dir = out / "session"
    session = replace(sim.session, meta=replace(sim.session.meta, design_alignment="alignment.xml"))
    write_session(session_dir, session, xml, overwrite=True,
                  extra_files={"truth.csv": lambda p: write_truth_csv(p, sim.truth, 0.1)})
    err.print("2/4 processing (dead reckoning, filtering, RTS smoothing) ...")
    result, _, written = run_process(session_dir, out / "processed")
    print_summary(result, written)
    err.print("3/4 survey sheet and plots ...")
    exported = export_outputs(out / "processed", out / "survey.xlsx", None, out / "plots")
    err.print("4/4 comparing with the simulator's truth ...")
    tj = result.trajectory
    e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, sim.truth)
    rms = np.array(e.rms_m()) * 1e3
    nr = e.normalised_rms()
    con.print(f"accuracy against the truth: RMS lateral {rms[0]:.3f} mm, vertical {rms[2]:.3f} mm, "
              f"longitudinal {rms[1]:.3f} mm; RMS error/sigma lateral {nr[0]:.2f}, vertical {nr[2]:.2f} "
              f"(1 = honest sigmas)", highlight=False)
    con.print(f"\nraw session:  {session_dir}\ntrack:        {written.track_csv}\n"
              f"survey sheet: {exported.xlsx}\nplots:        {out / 'plots'}\n"
              f"done in {time.perf_counter() - t_start:.1f} s", highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``demo`` to the trolley app."""
    app.command("demo")(demo)
