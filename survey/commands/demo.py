"""``trolley demo``: the whole chain on the sample project, in one command.

By default the demo runs a real field session (``trolley survey start --simulate --script``) on a
copy of ``projects/demo``: the truth simulator feeds the device twins, which stream over
pseudo-terminals to the drivers; the scripted crew sets up the free station on CPIII, waits for the
static alignment, takes a fix at every stop; every interval is filtered and smoothed as its closing
fix is accepted; at the end the whole session is re-processed, the Excel survey sheet and the plots
are written, and the track is compared with the simulator's truth.

``--direct`` is the short path without devices: simulate, write the raw session folder, process,
export, compare.
"""
from __future__ import annotations

import re
import shutil
import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console

from survey.atomicwrite import MARKER_NAME, OutputError, check_outputs, claim_folder, made_by, write_marker
from survey.commands.options import ImuPreset
from survey.commands.survey import MAX_SPEEDUP, SPEEDUP_WHY, session_outcome_dict

_REPO_DEMO = Path(__file__).resolve().parents[2] / "projects" / "demo"


def _guard_demo_store(root: Path) -> None:
    """Refuse to replace ``root`` (OUT/project) unless the demo made it: its marker, or (demos
    before the marker) nothing in it but the demo's own project folder with its store."""
    if not root.exists():
        return
    if made_by(root, "demo"):
        return
    entries = {p.name for p in root.iterdir()} if root.is_dir() else None
    if entries == {"demo"} and (root / "demo" / "project.sqlite").is_file() and \
            (root / "demo" / "project.toml").is_file():
        return
    raise OutputError(f"--out {root.parent}: {root} exists and was not made by `trolley demo`; the demo rebuilds "
                      "OUT/project on every run and never deletes a folder it did not make: choose another --out")


#: what the demo writes into its --out folder (the field session and --direct together)
DEMO_ENTRIES = frozenset({"project", "session", "processed", "plots", "survey.xlsx", "crew_script.txt", MARKER_NAME})


def _guard_demo_out(out: Path) -> None:
    """Refuse an --out folder that holds anything the demo did not make: the demo replaces its
    session/, processed/, plots/, survey.xlsx there (a user's folder of that name was deleted).
    Its own folder carries the marker; a demo output from before the marker holds only the
    demo's names and its marked project store or raw session."""
    if not out.exists():
        return
    if not out.is_dir():
        raise OutputError(f"--out {out}: exists and is not a folder")
    entries = {p.name for p in out.iterdir()}
    if not entries or made_by(out, "demo"):
        return
    if entries <= DEMO_ENTRIES:
        _guard_demo_store(out / "project")      # (its own message for a project folder of yours)
        if (out / "project").is_dir() or made_by(out / "session", "demo"):
            return
        _guard_demo_session(out)
    raise OutputError(f"--out {out}: exists, is not empty and was not made by `trolley demo` (no {MARKER_NAME}); "
                      "the demo writes project/, session/, processed/, plots/ and survey.xlsx there and never "
                      "writes over a folder it did not make: choose an empty or new folder")


def _guard_demo_session(out: Path) -> None:
    """Refuse OUT/session unless the demo made it: a raw session is recorded data."""
    session_dir = out / "session"
    if session_dir.is_dir() and any(session_dir.iterdir()) and not made_by(session_dir, "demo"):
        raise OutputError(f"--out {out}: {session_dir} exists and was not made by `trolley demo` (no {MARKER_NAME}); "
                          "the demo never replaces a raw session it did not make: choose another --out")


def _demo_project() -> Path:
    project = Path("projects/demo")
    return project if (project / "project.toml").exists() else _REPO_DEMO


def demo(
    out: Annotated[Optional[Path], typer.Option("--out", help="output folder (default: projects/demo/out)")] = None,
    imu: Annotated[Optional[ImuPreset], typer.Option(help="IMU grade (default: the project's)")] = None,
    seed: Annotated[Optional[int], typer.Option(help="random seed of the simulation")] = None,
    direct: Annotated[bool, typer.Option("--direct", help="skip the field session: simulate, process, export")] = False,
    speedup: Annotated[float, typer.Option(help="simulated seconds per wall-clock second in the field session")] = 40.0,
    json_output: Annotated[bool, typer.Option("--json", help="print where the results are and the accuracy "
                                                             "against the truth as one JSON object on stdout")] = False,
) -> None:
    """Survey the demo project end to end (field session with simulated devices); print where the results are."""
    from survey import jsonout
    from survey.commands.engine import fail
    from survey.limits import check_finite, check_seed

    try:
        check_finite(speedup, "--speedup", positive=True, maximum=MAX_SPEEDUP, why=SPEEDUP_WHY)
        check_seed(seed)
    except ValueError as exc:
        # one line as on every command (a BadParameter put it under typer's usage text)
        fail(str(exc))
    project = _demo_project()
    out = out if out is not None else project / "out"
    try:
        # never into a raw session or recording, never over a folder or a project store the demo
        # did not make; marked as the demo's before anything is written into it
        check_outputs([], folders=[("--out", out)])
        _guard_demo_out(out)
        if not direct:
            _guard_demo_store(out / "project")
        claim_folder(out, "demo")
    except OutputError as exc:
        fail(str(exc))
    con = Console(stderr=True) if json_output else Console()
    if direct:
        doc = demo_direct(project, out, imu, seed, con)
    else:
        doc = demo_session(project, out, imu, seed, speedup, con)
    if json_output:
        jsonout.echo(doc)


def _accuracy_line(con: Console, result, truth) -> dict:
    """Print the accuracy against the truth; returns it for ``--json`` (mm and error/sigma)."""
    import numpy as np

    from trolley.validation import track_errors

    tj = result.trajectory
    e = track_errors(tj.t_s, tj.distance_m, tj.enh_m, tj.sigma_enh_m, truth, cov_EN_m2=tj.cov_EN_m2)
    rms = np.array(e.rms_m()) * 1e3
    nr = e.normalised_rms()
    con.print(f"accuracy against the truth: RMS lateral {rms[0]:.3f} mm, vertical {rms[2]:.3f} mm, "
              f"longitudinal {rms[1]:.3f} mm; RMS error/sigma lateral {nr[0]:.2f}, vertical {nr[2]:.2f} "
              f"(1 = honest sigmas)", highlight=False)
    return {"rms_lateral_mm": rms[0], "rms_vertical_mm": rms[2], "rms_longitudinal_mm": rms[1],
            "normalised_rms_lateral": nr[0], "normalised_rms_vertical": nr[2]}


def demo_session(project: Path, out: Path, imu: Optional[str], seed: Optional[int], speedup: float,
                 con: Console | None = None) -> dict:
    """The demo through a scripted field session with the twins over ptys; returns what ``--json`` prints."""
    from survey.commands.engine import fail
    from survey.commands.project import new
    from survey.commands.survey import run_session
    from survey.session.script import survey_script
    from trolley.sensors import IMU_PRESETS

    con = con if con is not None else Console()
    err = Console(stderr=True)
    t_start = time.perf_counter()
    if imu is not None and imu not in IMU_PRESETS:
        fail(f"--imu: unknown IMU preset {imu!r} (choose {', '.join(IMU_PRESETS)})")
    root = out / "project"
    folder = root / "demo"
    try:
        _guard_demo_store(root)      # (the command checked it already; other callers of this function too)
    except OutputError as exc:
        fail(str(exc))
    if root.exists():
        shutil.rmtree(root)  # the demo's own copy of the project, rebuilt every run
    folder.mkdir(parents=True)
    write_marker(root, "demo")
    toml = (project / "project.toml").read_text(encoding="utf-8")
    if imu is not None:
        toml = re.sub(r'(?m)^preset\s*=\s*"[^"]*"', f'preset = "{imu}"', toml)
    if seed is not None:
        toml = re.sub(r"(?m)^seed\s*=\s*\d+", f"seed = {seed}", toml)
    (folder / "project.toml").write_text(toml, encoding="utf-8")
    for name in ("alignment.xml", "cpiii.csv"):
        shutil.copy(project / name, folder / name)
    err.print(f"1/3 project store {folder / 'project.sqlite'} from {project}", highlight=False, markup=False)
    new("demo", root=root, imu=None, latitude_deg=None, height=None, tolerance_set="default", use_toml=True)
    from survey.commands.survey import open_store, simulated_world

    with open_store(str(folder), root) as store:
        n_stops = simulated_world(store, speedup).sim.truth.motion.stop_chainage_m.size
    script = out / "crew_script.txt"
    script.write_text(survey_script(n_stops, note_every=5, station_every=5), encoding="utf-8")
    err.print(f"2/3 field session with simulated devices on ptys, {speedup:g}x real time, crew script {script}",
              highlight=False, markup=False)
    outcome = run_session(str(folder), "demo", root, None, True, script, speedup, out, resume=False, con=con,
                          out_checked=True)       # (--out was checked by the command: the demo's own folder)
    err.print("3/3 comparing with the simulator's truth ...")
    if outcome.result is None:
        fail("the session produced no processed track")
    accuracy = _accuracy_line(con, outcome.result, outcome.world.sim.truth)
    elapsed = time.perf_counter() - t_start
    con.print(f"project store: {folder / 'project.sqlite'}\ndone in {elapsed:.1f} s", highlight=False, markup=False)
    return {"mode": "field session", "project_store": folder / "project.sqlite",
            **session_outcome_dict(session_name="demo", outcome=outcome), "accuracy": accuracy,
            "elapsed_s": elapsed}


def demo_direct(project: Path, out: Path, imu: Optional[str], seed: Optional[int],
                con: Console | None = None) -> dict:
    """Simulate, write the raw session folder, process, export and compare with the truth; returns
    what ``--json`` prints."""
    from dataclasses import replace

    from survey.commands.engine import fail, print_summary, run_process
    from survey.commands.progress import progress_bar
    from survey.commands.simulate import ProjectFileError, project_settings
    from survey.export import export_outputs
    from survey.sessionio import write_session, write_truth_csv
    from trolley.landxml import parse_landxml
    from trolley.sensors import IMU_PRESETS
    from trolley.truthsim import SimulationConfig, simulate_survey

    con = con if con is not None else Console()
    err = Console(stderr=True)
    t_start = time.perf_counter()
    session_dir = out / "session"
    try:
        _guard_demo_session(out)    # (the command checked it already; other callers of this function too)
    except OutputError as exc:
        fail(str(exc))
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
              f"at {config.imu_rate_hz:g} Hz ...", highlight=False, markup=False)
    sim = simulate_survey(design, config)
    session = replace(sim.session, meta=replace(sim.session.meta, design_alignment="alignment.xml"))
    write_session(session_dir, session, xml, overwrite=True,
                  extra_files={"truth.csv": lambda p: write_truth_csv(p, sim.truth, 0.1)})
    write_marker(session_dir, "demo")
    err.print("2/4 processing (dead reckoning, filtering, RTS smoothing) ...")
    result, _, written = run_process(session_dir, out / "processed")
    print_summary(result, written, con)
    err.print("3/4 survey sheet and plots ...")
    with progress_bar("computing the track geometry", err) as report:
        exported = export_outputs(out / "processed", out / "survey.xlsx", None, out / "plots",
                                  project_name=project.resolve().name, session_name="simulated (direct)",
                                  progress=report)
    err.print("4/4 comparing with the simulator's truth ...")
    accuracy = _accuracy_line(con, result, sim.truth)
    con.print(f"\nraw session:  {session_dir}\ntrack:        {written.track_csv}\n"
              f"survey sheet: {exported.xlsx}", highlight=False, markup=False)
    for i, png in enumerate(exported.plots):
        con.print(f"{'plots:' if i == 0 else '':14}{png}", highlight=False, markup=False)
    elapsed = time.perf_counter() - t_start
    con.print(f"done in {elapsed:.1f} s", highlight=False)
    return {"mode": "direct", "raw_session": session_dir, "track_csv": written.track_csv,
            "summary_json": written.summary_json, "xlsx": exported.xlsx, "plots": list(exported.plots),
            "accuracy": accuracy, "elapsed_s": elapsed}


def register(app: typer.Typer) -> None:
    """Add ``demo`` to the trolley app."""
    app.command("demo")(demo)
