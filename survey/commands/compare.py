"""``trolley compare``: two surveys of one track, their differences judged against their sigmas.

A repeat survey (or a forward and a backward run) checks the system and its sigmas; surveys
before and after track work show where the track moved. Reads two track.csv files (or output
folders holding them), writes the difference table and its plot, prints the verdict and a JSON
summary (docs/track_geometry.md, "Two surveys of one track"; ``trolley.repeatability``).
"""
from __future__ import annotations

import math
from pathlib import Path

import typer

from survey.commands.options import JsonAlways

#: the largest --limit (sigmas) and --max-offset-m (m) taken
MAX_LIMIT_SIGMA = 100.0
MAX_OFFSET_LIMIT_M = 10.0


def compare(
    track_a: Path = typer.Argument(..., metavar="TRACK_A", help="the reference survey: track.csv or an output folder "
                                                                "holding it (as `trolley export` takes it)"),
    track_b: Path = typer.Argument(..., metavar="TRACK_B", help="the survey compared with it (B - A is reported)"),
    csv: Path = typer.Option(None, "--csv", help="difference table to write (one row per station of A)."),
    plot: Path = typer.Option(None, "--plot", help="PNG of the differences with their +-limit sigma band."),
    limit: float = typer.Option(4.0, "--limit", help="a difference beyond this many of its sigmas is reported "
                                                     "(0-100]."),
    max_offset_m: float = typer.Option(0.5, "--max-offset-m", help="stations of A farther than this from B are "
                                                                   "not compared, m (0-10]."),
    fail_on_disagreement: bool = typer.Option(False, "--fail-on-disagreement",
                                              help="exit with code 1 when a difference is beyond the limit "
                                                   "(or differs where both sigmas are zero)."),
    json_output: JsonAlways = False,
) -> None:
    """Compare two surveys of one track: lateral, vertical, cant and gauge differences against their sigmas."""
    from rich.console import Console
    from rich.markup import escape

    from survey import jsonout
    from survey.atomicwrite import all_or_nothing, check_outputs, check_suffix, write_csv_frame
    from survey.comparison import compared_tracks, difference_frame, summary_dict, write_difference_plot
    from survey.limits import check_finite
    from survey.track_reader import resolve_track_csv

    console = Console(stderr=True)
    # bad input (ValueError: the track readers', the output checks') and OSError come out as one
    # line with exit code 2 through the app's guard (survey.errors.guarded)
    check_finite(limit, "--limit", positive=True, maximum=MAX_LIMIT_SIGMA)
    check_finite(max_offset_m, "--max-offset-m", positive=True, maximum=MAX_OFFSET_LIMIT_M,
                 why="farther apart, they are not surveys of one track")
    # the plot is a PNG whatever its name: --plot d.pdf wrote a PNG named d.pdf
    check_suffix("--csv", csv, ".csv", "a CSV table")
    check_suffix("--plot", plot, ".png", "a PNG image")
    inputs = [resolve_track_csv(track_a), resolve_track_csv(track_b)]
    check_outputs([("--csv", csv), ("--plot", plot)], inputs=inputs)
    ct = compared_tracks(track_a, track_b, limit, max_offset_m)
    with all_or_nothing():
        if csv is not None:
            write_csv_frame(csv, difference_frame(ct), float_format="%.4f")
        if plot is not None:
            write_difference_plot(plot, ct)
    for note in ct.a.notes + ct.b.notes:
        console.print(f"note: {note}", highlight=False, markup=False, soft_wrap=True)
    summary = summary_dict(ct)
    c = ct.comparison
    parts = []
    for q in ("lateral", "vertical", "cant", "gauge"):
        if math.isfinite(summary["rms_mm"][q]):  # both tracks have it
            z, sig, top = c.rms_z.get(q), summary["sigma_median_mm"].get(q), summary["sigma_max_mm"].get(q)
            # the largest sigma too: two surveys agree within a large one, e.g. where fixes were rejected
            parts.append(f"{q} RMS {summary['rms_mm'][q]:.3f} mm" + (
                f" (sigma {sig:.3f} mm median, {top:.3f} mm largest; RMS diff/sigma {z:.2f})"
                if z is not None and math.isfinite(z) else ""))
    console.print(f"{c.common_m:.1f} m compared ({summary['stations_compared']} of {summary['stations']} stations "
                  f"of A): " + "; ".join(parts), highlight=False, soft_wrap=True)
    for s in summary["stretches_beyond"]:
        console.print(f"[red]beyond {c.limit:g} sigma[/red]: {s['quantity']} {s['from_chainage_m']:.3f}-"
                      f"{s['to_chainage_m']:.3f} m, up to {s['max_abs_diff_mm']:.2f} mm ({s['max_abs_z']:.1f} sigma at "
                      f"{s['at_chainage_m']:.3f} m)", highlight=False, soft_wrap=True)
    zero = ", ".join(f"{q} at {n} stations" for q, n in c.zero_sigma.items() if n)
    if c.stretches:
        verdict = (f"[red]{len(c.stretches)} stretch(es) beyond {c.limit:g} sigma[/red]: a blunder, too small a "
                   "sigma, or the track moved between the surveys")
    elif zero:
        verdict = (f"[red]not judged[/red]: the surveys differ where both files give a zero sigma ({zero}); "
                   "a difference cannot be within a zero sigma")
    else:
        verdict = "[green]the surveys agree[/green] within their sigmas"
    console.print(f"B = {escape(str(ct.b_path))} minus A = {escape(str(ct.a_path))}: {verdict}", soft_wrap=True)
    jsonout.echo(summary)
    if fail_on_disagreement and not c.agree:
        raise typer.Exit(code=1)


def register(app: typer.Typer) -> None:
    """Add ``trolley compare`` to the app."""
    app.command("compare")(compare)
