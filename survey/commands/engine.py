"""``trolley process``: filter and smooth a raw session folder into ``track.csv``.

Bad input (a malformed session folder, an unreadable design) is reported in one line naming the
file, row and column, with exit code 2 and no output written.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer
from rich.console import Console

from survey.commands.options import Smoother, old_name, renamed
from survey.limits import check_allocation, check_finite

err = Console(stderr=True)


#: this many fixes rejected one after another are warned about (summary.json longest_rejected_run)
REJECTED_RUN_WARNING = 3


#: the longest station step of track.csv: --step-m 1e6 wrote a track of one station
MAX_STEP_M = 100.0
STEP_WHY = "the track is given at least every 100 m"


def fail(message: str, code: int = 2) -> None:
    """Print a one-line error to stderr (literally: no markup from the data) and exit non-zero."""
    from rich.text import Text

    # the message as text, not markup: "[site] crs" must print as written
    err.print(Text.assemble(("error: ", "bold red"), message), highlight=False, soft_wrap=True)
    raise typer.Exit(code=code)


def process(
    session_dir: Annotated[Path, typer.Argument(help="raw session folder (FORMATS.md section 1)")],
    out: Annotated[Path, typer.Option("--out", help="output folder for track.csv, fixes.csv, summary.json")],
    smoother: Annotated[Smoother, typer.Option(help="rts (Rauch-Tung-Striebel) or tfs (two-filter); "
                                                    "none = filtered only")] = "rts",
    step_m: Annotated[float, typer.Option("--step-m", help="chainage step of the output stations, m")] = 0.625,
    observability: Annotated[bool, typer.Option(
        "--observability", help="also report the observability ranks of the session's interval models "
                                "(Jiang 2017 Eq. 26; imports python-control, about 1 s more)")] = False,
    json_output: Annotated[bool, typer.Option("--json", help="print the summary as one JSON object on "
                                                             "stdout, nothing else")] = False,
    accept_fix: Annotated[Optional[list[str]], typer.Option(
        "--accept-fix", metavar="POINT", help="use this fix (its point label in fixes.csv) whatever the gate and "
                                              "the data snooping say; repeat for more")] = None,
    step_old: Annotated[Optional[float], typer.Option("--step", hidden=True, help=old_name("--step-m"))] = None,
) -> None:
    """Filter and smooth a raw stop-and-go session into track.csv (Jiang 2017)."""
    step_option = "--step" if step_old is not None else "--step-m"
    step_m = renamed(step_m, step_old, "--step-m", "--step", 0.625)
    try:
        check_finite(step_m, step_option, positive=True, maximum=MAX_STEP_M, why=STEP_WHY)
    except ValueError as exc:
        fail(str(exc))
    result, session, written = run_process(session_dir, out, smoother, step_m, force_accept=tuple(accept_fix or ()),
                                           observability=observability)
    if json_output:
        from survey import jsonout
        from survey.trackio import summary_dict

        doc = summary_dict(result, session, session_dir)
        doc.update(track_csv=written.track_csv, fixes_csv=written.fixes_csv, summary_json=written.summary_json,
                   rejected_fixes=[{"point": result.fixes.point[i], "t_s": result.fixes.t_s[i],
                                    "reason": result.fixes.reason[i]}
                                   for i in range(len(result.fixes.t_s)) if not result.fixes.accepted[i]])
        jsonout.echo(doc)
    else:
        print_summary(result, written)


#: Memory one output station needs through resampling and writing (about 60 float columns), bytes.
_STATION_BYTES = 512

#: Share of the progress bar for reading the session before processing, and for writing after.
_READ_SHARE, _WRITE_SHARE = 0.15, 0.05


def run_process(session_dir: Path, out: Path, smoother: str = "rts", step: float = 0.625,
                force_accept: tuple[str, ...] = (), observability: bool = False,
                project_name: str | None = None, session_name: str | None = None):
    """Read, process and write one session; exits with a clear message on bad input.

    The progress bar follows the engine's own sub-steps (dead reckoning, each filter and
    smoother pass node by node, stations) through the ``progress`` callback of
    :func:`trolley.engine.process_session`. The observability ranks (python-control, a slow
    import) are computed only with ``observability=True``.
    """
    from survey.commands.progress import progress_bar, share
    from survey.sessionio import SessionFormatError, read_design, read_session
    from survey.trackio import OutputFolderError, write_outputs
    from trolley.engine import ProcessConfig, process_session

    if smoother not in ("rts", "tfs", "none"):
        fail(f"--smoother must be rts, tfs or none, not {smoother!r}")
    try:
        check_finite(step, "--step-m", positive=True, maximum=MAX_STEP_M, why=STEP_WHY)
    except ValueError as exc:
        fail(str(exc))
    if not session_dir.is_dir():
        fail(f"{session_dir}: no such session folder")
    if not (session_dir / "session.toml").is_file():
        # a folder from the wrong step: say what it is and what to run instead of "file missing"
        if (session_dir / "session" / "session.toml").is_file():
            fail(f"{session_dir}: a field-session or demo output folder, not a raw session; its raw session is "
                 f"{session_dir / 'session'} (`trolley process {session_dir / 'session'} --out OUT`), and its "
                 f"processed track is exported with `trolley export {session_dir} --xlsx FILE`")
        if (session_dir / "track.csv").is_file():
            fail(f"{session_dir}: a processed track (track.csv), not a raw session (no session.toml): "
                 f"export it with `trolley export {session_dir} --xlsx FILE`")
    design_notes: list[str] = []
    with progress_bar("reading the session", err) as report:
        try:
            session = read_session(session_dir)
            design = read_design(session_dir, session.meta, design_notes)
        except SessionFormatError as exc:
            fail(str(exc))
        except ValueError as exc:  # a LandXmlError is a ValueError naming the element
            fail(f"{session_dir}: {exc}")
        report("processing", _READ_SHARE)
        duration_s = float(session.imu_t_s[-1] - session.imu_t_s[0])
        from trolley.deadreckoning import MIN_STATIC_SAMPLES

        n_static = int(np.count_nonzero(session.imu_t_s <= session.imu_t_s[0] + session.meta.static_s))
        if n_static < MIN_STATIC_SAMPLES:
            fail(f"{session_dir / 'session.toml'}: key alignment.static_s: {session.meta.static_s:g} s holds "
                 f"{n_static} IMU sample(s) of imu.csv; the static alignment needs at least {MIN_STATIC_SAMPLES}")
        if session.meta.static_s >= duration_s:
            fail(f"{session_dir / 'session.toml'}: key alignment.static_s: {session.meta.static_s:g} s is not "
                 f"shorter than the IMU data ({duration_s:g} s in imu.csv); nothing would be left to survey")
        unknown = sorted(set(force_accept) - {str(p) for p in session.fixes.point})
        if unknown:
            fail(f"--accept-fix {unknown[0]}: no fix with this point in {session_dir / 'fixes.csv'}")
        span_m = float(np.ptp(session.odo_distance_m)) if session.odo_distance_m.size else 0.0
        try:
            # stations: a few dozen float columns each through resampling and writing
            check_allocation(span_m / step + 1, _STATION_BYTES, f"--step-m {step:g} over {span_m:.1f} m")
        except ValueError as exc:
            fail(str(exc))
        try:
            result = process_session(session, design, ProcessConfig(smoother=smoother, step_m=step,
                                                                   force_accept=force_accept),
                                     with_observability=observability,
                                     progress=share(report, _READ_SHARE, 1.0 - _WRITE_SHARE))
        except ValueError as exc:
            fail(f"{session_dir}: {exc}")
        if result.stations.chainage_m.size == 0:
            fail(f"{session_dir}: no track stations (the trolley did not move between two fixes); nothing written")
        report("writing the outputs", 1.0 - _WRITE_SHARE)
        try:
            written = write_outputs(out, result, session, session_dir,
                                    None if design is None else design.stationing, project_name, session_name)
        except OutputFolderError as exc:
            fail(str(exc))
        except OSError as exc:
            fail(f"{out}: cannot write the outputs: {exc}")
        report("done", 1.0)
    for note in design_notes:
        err.print(f"note: {note}", highlight=False, soft_wrap=True, markup=False)
    return result, session, written


def print_summary(result, written, con: Console | None = None) -> None:
    """A short summary of a processing run on the terminal (``con``, default stdout)."""
    from rich.table import Table
    from rich.text import Text

    from trolley import units

    s = result.summary
    st = result.stations
    t = Table(title="trolley process", show_header=False)
    t.add_column("what")
    t.add_column("value", justify="right")
    t.add_row("fixes used / rejected", f"{s['fixes_used']} / {s['fixes_rejected']}")
    rms = s["rms_innovation_m"]
    t.add_row("RMS of innovations", f"{units.m_to_mm(rms):.2f} mm" if math.isfinite(rms) else
              "none (no fix after the first was used)")
    t.add_row("max 1-sigma of the track", f"{units.m_to_mm(s['max_sigma_m']):.2f} mm")
    t.add_row("stations", f"{len(st.chainage_m)} ({result.config.step_m} m step)")
    if len(st.chainage_m):
        t.add_row("chainage", f"{st.chainage_m[0]:.3f} .. {st.chainage_m[-1]:.3f} m")
    t.add_row("initial heading", f"{s['initial_heading_deg']:.4f} deg ({s['heading_source']}, "
                                 f"1-sigma {s['heading_sigma_deg']:.3f} deg)")
    if result.observability_ranks:
        t.add_row("observability ranks", f"vertical {result.observability_ranks[0]}/3, "
                                         f"level {result.observability_ranks[1]}/5")
    t.add_row("smoother", result.config.smoother)
    con = con if con is not None else Console()
    con.print(t)
    f = result.fixes
    for i in range(len(f.t_s)):
        if not f.accepted[i]:
            err.print(Text.assemble(("rejected fix", "yellow"), f" {f.point[i]} at t="
                                    f"{f.t_s[i]:.1f} s: {f.reason[i].removeprefix('rejected: ')}"), highlight=False)
        elif f.reason[i].startswith("taken back"):
            err.print(Text.assemble(("fix taken back", "cyan"), f" {f.point[i]} at t="
                                    f"{f.t_s[i]:.1f} s: {f.reason[i].removeprefix('taken back: ')}"), highlight=False)
    run = s["longest_rejected_run"]
    if run >= REJECTED_RUN_WARNING:
        err.print(Text.assemble(("warning", "bold yellow"), (
            f": {run} fixes in a row were rejected; across them the track is dead reckoning (max 1-sigma "
            f"{units.m_to_mm(s['max_sigma_m']):.1f} mm). Each was tested against the smoothed track of all "
            "the other fixes as well, and disagrees with it: the fixes are likely wrong (a station setup, a "
            "target), or the dead reckoning turned between them by more than its model allows. Check their "
            "NIS in fixes.csv before using this track.")), highlight=False)
    con.print(f"track:   {written.track_csv}\nfixes:   {written.fixes_csv}\nsummary: {written.summary_json}",
              markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``process`` to the trolley app."""
    app.command("process")(process)
