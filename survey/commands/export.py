"""``trolley export``: the survey sheet of a processed track (xlsx, CSV, PNG plots).

Reads track.csv (or a processing output folder holding it, with fixes.csv and summary.json, or a
field-session output folder holding processed/track.csv), computes the geometry parameters, checks them against a tolerance set and writes the outputs
(docs/track_geometry.md). A JSON summary goes to stdout; errors are one line on stderr, exit 2.
"""
from __future__ import annotations

from enum import Enum
from pathlib import Path

import typer
from rich.markup import escape

from survey.commands.options import JsonAlways, old_name, renamed
from survey.errors import refuse


#: the outputs an export writes (option, metavar): without one (and without --fail-on-defects or
#: --json, which make the check itself the purpose) there is nothing to do
OUTPUT_OPTIONS = (("--xlsx", "FILE"), ("--pdf", "FILE"), ("--csv", "FILE"), ("--plots", "FOLDER"))

#: the longest twist base, versine chord or gauge-rate base, m: 1e300 gave a sheet whose columns
#: of that base were all empty
MAX_BASE_M = 1000.0


class LateralSign(str, Enum):
    right = "right"
    left = "left"


class CantSign(str, Enum):
    left_high = "left_high"
    right_high = "right_high"


class VersineSign(str, Enum):
    centre_minus_chord = "centre_minus_chord"
    chord_minus_centre = "chord_minus_centre"


def export(
    track: Path = typer.Argument(..., metavar="TRACK_CSV_OR_SESSION",
                                 help="track.csv; a processing output folder holding track.csv "
                                      "(`trolley process SESSION --out OUT`); or a field-session / demo "
                                      "output folder holding processed/track.csv. A raw session folder "
                                      "must be processed first."),
    xlsx: Path = typer.Option(None, "--xlsx", help="Excel survey sheet to write."),
    pdf: Path = typer.Option(None, "--pdf", help="PDF report to write (cover with the survey header, summary, "
                                                 "strip charts per km, defects, free-station QA)."),
    tolerances: str = typer.Option("hsr_ballastless_static", "--tolerances",
                                   help="Built-in tolerance set (hsr_ballastless_static, en13848_5_alert) or a TOML file."),
    csv: Path = typer.Option(None, "--csv", help="Track table as CSV (injection-safe)."),
    plots: Path = typer.Option(None, "--plots", help="Folder for PNG plots."),
    design: Path = typer.Option(None, "--design", help="LandXML design alignment (default: the one the session names)."),
    design_name: str = typer.Option(None, "--design-name", help="the alignment to read from a LandXML file holding "
                                                                "several (default: the session's [design] name)."),
    twist_base_m: float = typer.Option(None, "--twist-base-m", help="Twist base, m (default from the tolerance set, else 3)."),
    chord_m: float = typer.Option(None, "--chord-m", help="Versine chord, m (default from the tolerance set, else 10)."),
    gauge_rate_base_m: float = typer.Option(None, "--gauge-rate-base-m", help="Gauge change-rate base, m."),
    lateral_sign: LateralSign = typer.Option(LateralSign.right, "--lateral-sign", help="Side that is positive for lateral values."),
    cant_sign: CantSign = typer.Option(CantSign.left_high, "--cant-sign", help="Cant positive when this rail is higher."),
    versine_sign: VersineSign = typer.Option(VersineSign.centre_minus_chord, "--versine-sign", help="Versine sign convention."),
    project: str = typer.Option(None, "--project", help="Project name for the Summary sheet (default: summary.json's)."),
    session: str = typer.Option(None, "--session", help="Session name for the Summary sheet (default: summary.json's)."),
    fail_on_defects: bool = typer.Option(False, "--fail-on-defects", help="Exit with code 1 when any defect is found."),
    json_output: JsonAlways = False,
    twist_base_old: float = typer.Option(None, "--twist-base", hidden=True, help=old_name("--twist-base-m")),
    chord_old: float = typer.Option(None, "--chord", hidden=True, help=old_name("--chord-m")),
    gauge_rate_base_old: float = typer.Option(None, "--gauge-rate-base", hidden=True,
                                              help=old_name("--gauge-rate-base-m")),
) -> None:
    """Compute track geometry, check tolerances, write the Excel survey sheet / PDF report / CSV / plots."""
    from rich.console import Console

    from survey import jsonout
    from survey.commands.progress import progress_bar
    from survey.export import export_outputs, unchecked_notes
    from survey.limits import check_finite
    from survey.track_reader import ExportInputError
    from trolley.tolerances import ToleranceError

    # a bad value is named as it was typed, old name or new
    typed = {new: old if old_value is not None else new for new, old, old_value in (
        ("--twist-base-m", "--twist-base", twist_base_old), ("--chord-m", "--chord", chord_old),
        ("--gauge-rate-base-m", "--gauge-rate-base", gauge_rate_base_old))}
    twist_base_m = renamed(twist_base_m, twist_base_old, "--twist-base-m", "--twist-base")
    chord_m = renamed(chord_m, chord_old, "--chord-m", "--chord")
    gauge_rate_base_m = renamed(gauge_rate_base_m, gauge_rate_base_old, "--gauge-rate-base-m", "--gauge-rate-base")
    console = Console(stderr=True)
    asked = [value for value in (xlsx, pdf, csv, plots) if value is not None]
    if not asked and not (fail_on_defects or json_output):
        # it computed everything, wrote nothing and exited 0: a forgotten --xlsx looked like a success
        outputs = ", ".join(f"{option} {metavar}" for option, metavar in OUTPUT_OPTIONS)
        refuse(f"nothing to write: give one or more of {outputs} (or --fail-on-defects or --json to check the "
               "track without writing a file)")
    for option, value in ((typed["--twist-base-m"], twist_base_m), (typed["--chord-m"], chord_m),
                          (typed["--gauge-rate-base-m"], gauge_rate_base_m)):
        try:
            check_finite(value, option, positive=True, maximum=MAX_BASE_M,
                         why="the longest chord of the track standards is 300 m")
        except ValueError as e:
            typer.echo(f"error: {e}", err=True)
            raise typer.Exit(code=2)
    try:
        with progress_bar("computing the track geometry", console) as report:
            result = export_outputs(track, xlsx, csv, plots, tolerances=tolerances, design=design,
                                    design_name=design_name,
                                    project_name=project, session_name=session, progress=report, pdf=pdf,
                                    twist_base_m=twist_base_m, versine_chord_m=chord_m,
                                    gauge_rate_base_m=gauge_rate_base_m, lateral_sign=lateral_sign.value,
                                    cant_sign=cant_sign.value, versine_sign=versine_sign.value)
    except ToleranceError as e:
        # named as `project new --tolerances` names it: a mistyped set name said only "NAME: neither ..."
        typer.echo("error: --tolerances: " + " ".join(str(e).split()), err=True)
        raise typer.Exit(code=2)
    except (ExportInputError, ValueError) as e:
        typer.echo("error: " + " ".join(str(e).split()), err=True)
        raise typer.Exit(code=2)
    except OSError as e:
        typer.echo(f"error: {e.filename or ''}: {e.strerror or e}", err=True)
        raise typer.Exit(code=2)
    rep = result.report
    for note in unchecked_notes(rep):   # what was not checked, before a PASS is believed
        console.print(f"note: {note}", highlight=False, markup=False, soft_wrap=True)
    verdict = "[green]PASS[/green]" if result.passed else f"[red]FAIL[/red]: {result.defects} defect(s)"
    console.print(f"{rep.geometry.chainage_m.size} stations, tolerances {escape(rep.tolerances.name)}: {verdict}")
    if not asked:
        console.print("note: no output file asked for (" + ", ".join(o for o, _ in OUTPUT_OPTIONS) +
                      "): nothing written", highlight=False, markup=False, soft_wrap=True)
    jsonout.echo(result.as_dict())
    if fail_on_defects and not result.passed:
        raise typer.Exit(code=1)


def register(app: typer.Typer) -> None:
    """Add ``trolley export`` to the app."""
    app.command("export")(export)
