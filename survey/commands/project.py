"""``trolley project ...``: create a project store, import CPIII points, the design alignment and
raw session folders, export sessions, set the survey header fields, and show what a project holds.

Every command opens ``<root>/<name>/project.sqlite`` (``--root``, default ``projects``, or the
environment variable ``TROLLEY_PROJECTS``). Bad input is one line on stderr naming the file and
line, exit code 2, and nothing stored (each import is one transaction).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from survey import jsonout
from survey.commands.options import ImuPreset, JsonFlag, old_name, renamed

err = Console(stderr=True)
project_app = typer.Typer(help="Project store: CPIII points, design alignment, sessions.", no_args_is_help=True,
                          rich_markup_mode=None)

RootOption = Annotated[Path, typer.Option("--root", envvar="TROLLEY_PROJECTS",
                                          help="folder holding the projects")]
ProjectOption = Annotated[str, typer.Option("--project", "-p", help="project name")]


def say(message: str) -> None:
    """A status line on stderr (never wrapped, so it can be grepped)."""
    err.print(message, highlight=False, soft_wrap=True, markup=False)


def result(message: str, json_output: bool) -> None:
    """The command's result line: on stdout, where every command prints its result
    (docs/conventions.md); with --json on stderr, so that stdout is the one JSON object."""
    (err if json_output else Console()).print(message, highlight=False, soft_wrap=True, markup=False)


def fail(message: str, code: int = 2) -> None:
    """Print a one-line error to stderr and exit non-zero."""
    from rich.text import Text

    err.print(Text.assemble(("error: ", "bold red"), message), highlight=False, soft_wrap=True)
    raise typer.Exit(code=code)


def _open(root: Path, name: str):
    from survey.store import ProjectStore, StoreError

    try:
        return ProjectStore.open_project(root, name)
    except StoreError as e:
        fail(str(e))


@project_app.command("new")
def new(
    name: Annotated[str, typer.Argument(help="project name (a folder under --root)")],
    root: RootOption = Path("projects"),
    imu: Annotated[ImuPreset | None, typer.Option(help="IMU preset [default: project.toml or rlg]")] = None,
    latitude_deg: Annotated[float | None, typer.Option(help="site latitude, degrees [default: project.toml or 28]")] = None,
    height: Annotated[float | None, typer.Option("--height-m", help="site height, m [default: project.toml or 50]")] = None,
    tolerance_set: Annotated[str, typer.Option("--tolerances", help="tolerance set for defects: default, a built-in "
                                                                    "set name or a TOML file")] = "default",
    use_toml: Annotated[bool, typer.Option("--toml/--no-toml", help="take settings, design and CPIII from "
                                           "<root>/<name>/project.toml when it exists")] = True,
    json_output: JsonFlag = False,
    height_old: Annotated[float | None, typer.Option("--height", hidden=True, help=old_name("--height-m"))] = None,
    tolerance_set_old: Annotated[str | None, typer.Option("--tolerance-set", hidden=True,
                                                          help=old_name("--tolerances"))] = None,
) -> None:
    """Create a project store <root>/<name>/project.sqlite.

    When the folder already holds a project.toml (as projects/demo does), its [site], [imu] preset,
    [trolley], [totalstation] prism constants and [simulation] static_s / fix_sigma_m become the settings, and the design
    alignment and CPIII file named in [design] are imported. Options override the file.
    """
    import dataclasses

    import numpy as np

    from survey.commands.simulate import SITE_HEIGHT_RANGE_M
    from survey.cpiii import CpiiiError, read_cpiii_file
    from survey.limits import check_finite
    from survey.names import UnsafeNameError, check_name, inside
    from survey.store import ProjectSettings, ProjectStore, StoreError, alignment_record_from_text, project_path
    from trolley import units
    from trolley.earth import MAX_LATITUDE_DEG
    from trolley.sensors import IMU_PRESETS

    height_option = "--height" if height_old is not None else "--height-m"   # named as typed
    height = renamed(height, height_old, "--height-m", "--height")
    try:
        check_name("project name", name)
        # the options before any file is read: a bad one is named whatever the folder holds
        check_finite(latitude_deg, "--latitude-deg", minimum=-MAX_LATITUDE_DEG, maximum=MAX_LATITUDE_DEG,
                     why="no north-seeking alignment near the poles")
        check_finite(height, height_option, minimum=SITE_HEIGHT_RANGE_M[0], maximum=SITE_HEIGHT_RANGE_M[1])
    except ValueError as e:       # UnsafeNameError is one
        fail(str(e))
    if Path(root).exists() and not Path(root).is_dir():
        fail(f"--root {root}: is a file, not a folder of projects")
    tolerance_option = "--tolerance-set" if tolerance_set_old is not None else "--tolerances"
    tolerance_set = renamed(tolerance_set, tolerance_set_old, "--tolerances", "--tolerance-set", "default")
    settings = ProjectSettings()
    folder = Path(root) / name
    design = points = None
    if project_path(root, name).exists():
        fail(f"project {name!r} already exists: {project_path(root, name)}")
    if use_toml and (folder / "project.toml").is_file():
        # everything is read and checked before the store is created: a bad file creates nothing
        import tomllib

        from survey.commands.simulate import ProjectFileError, project_settings

        try:
            kwargs, preset, xml = project_settings(folder, project_keys=True)
            data = tomllib.loads((folder / "project.toml").read_text(encoding="utf-8-sig"))
        except (ProjectFileError, tomllib.TOMLDecodeError) as e:
            fail(str(e))
        if preset not in IMU_PRESETS:
            fail(f"{folder / 'project.toml'}: key imu.preset: {preset!r} is not one of {', '.join(IMU_PRESETS)}")
        fields = {f.name for f in dataclasses.fields(ProjectSettings)}
        settings = dataclasses.replace(settings, imu=IMU_PRESETS[preset],
                                       **{k: v for k, v in kwargs.items() if k in fields})
        design_name = data.get("design", {}).get("alignment")
        try:
            design = alignment_record_from_text(design_name, xml, settings.trolley.rail_spacing_m)
        except ValueError as e:
            fail(f"{folder / design_name}: {e}")
        cpiii_name = data.get("design", {}).get("cpiii")
        if isinstance(cpiii_name, str):
            try:
                points = read_cpiii_file(inside(folder, cpiii_name, f"{folder / 'project.toml'}: key design.cpiii"))
            except (CpiiiError, UnsafeNameError) as e:
                fail(str(e))
    if imu is not None:
        settings = dataclasses.replace(settings, imu=IMU_PRESETS[imu])
    if latitude_deg is not None:
        settings = dataclasses.replace(settings, latitude_rad=units.deg_to_rad(latitude_deg))
    if height is not None:
        settings = dataclasses.replace(settings, height_m=height)
    from survey.session.interval import tolerance_set as load_tolerance_set
    from trolley.tolerances import ToleranceError

    try:
        load_tolerance_set(tolerance_set)
    except ToleranceError as e:
        fail(f"{tolerance_option}: {e}")
    settings = dataclasses.replace(settings, tolerance_set=tolerance_set)
    toml_crs = None
    if settings.crs:
        from trolley.projection import CrsError, crs_info, site_factors

        try:
            toml_crs = crs_info(settings.crs)
            if points:
                site_factors(toml_crs.text, np.array([[p.e_m, p.n_m, p.h_m] for p in points]))
        except CrsError as e:
            fail(f"{folder / 'project.toml'}: key site.crs: {e}")
    try:
        store = ProjectStore.create(root, name, settings)
    except StoreError as e:
        fail(str(e))
    with store:
        if design is not None:
            store.add_alignment(design)
        if points is not None:
            store.add_cpiii_points(points)
        # a project.toml's [site] crs wins (checked before the store was created); else the
        # design's <CoordinateSystem>
        crs_notes = []
        if toml_crs is not None:
            apply_crs(store, toml_crs, settings.vertical_datum or toml_crs.vertical_datum or None)
        elif design is not None:
            crs_notes = design_crs(store, folder / design_name, xml)
    say(f"created project {name}: {store.path}")
    if design is not None:
        say(f"  design {design.name!r} ({design.file_name}): {design.element_count} elements, chainage "
            f"{design.chainage_start_m:.3f} .. {design.chainage_end_m:.3f} m")
    if points is not None:
        say(f"  {len(points)} CPIII points from {points[0].source}")
    for note in crs_notes:
        say(f"  note: {note}")
    if json_output:
        jsonout.echo({"project": name, "store": store.path,
                      "design": None if design is None else {
                          "name": design.name, "file": design.file_name, "elements": design.element_count,
                          "chainage_start_m": design.chainage_start_m, "chainage_end_m": design.chainage_end_m},
                      "cpiii_points": 0 if points is None else len(points)})


@project_app.command("import-cpiii")
def import_cpiii(
    file: Annotated[Path, typer.Argument(help="CPIII file: CSV id,E_m,N_m,H_m or Leica GSI-8/16 (words 11, 81-83)")],
    project: ProjectOption,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Import CPIII control points (all or nothing)."""
    from survey.cpiii import CpiiiError, import_cpiii_file

    with _open(root, project) as store:
        try:
            res = import_cpiii_file(store, file)
        except CpiiiError as e:
            fail(f"{e} (nothing imported)")
        total = len(store.cpiii_points())
    extra = f", {res.already_present} already present" if res.already_present else ""
    result(f"{file}: {res.added} CPIII points imported{extra}; the project has {total}", json_output)
    if json_output:
        jsonout.echo({"file": file, "added": res.added, "already_present": res.already_present, "total": total})


@project_app.command("import-alignment")
def import_alignment(
    file: Annotated[Path, typer.Argument(help="LandXML 1.2 design alignment")],
    project: ProjectOption,
    name: Annotated[str | None, typer.Option("--name", help="Alignment/@name to import from a file that "
                                                            "holds several")] = None,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Import the design alignment (LandXML kept verbatim; it becomes the project's current design).

    A file with several alignments needs --name; without it their names are listed (exit 2). What
    the reader skipped or tolerated (Feature elements, small gaps at joins, ...) is printed as notes.
    """
    from survey.store import alignment_record_from_text
    from trolley.landxml import AlignmentChoiceError, LandXmlError, decoded_landxml

    try:
        text = decoded_landxml(file.read_bytes())
    except OSError as e:
        fail(f"{file}: {e.strerror or e}")
    except LandXmlError as e:
        fail(f"{file}: {e}")
    with _open(root, project) as store:
        try:
            rec = alignment_record_from_text(file.name, text, store.settings().trolley.rail_spacing_m, name)
        except AlignmentChoiceError as e:
            listing = "\n".join(f"  {n}" for n in e.names)
            fail(f"{file}: {e} (nothing imported); the alignments in the file:\n{listing}\n"
                 f"import one with --name NAME")
        except ValueError as e:  # LandXmlError names the element
            fail(f"{file}: {e} (nothing imported)")
        store.add_alignment(rec)
        crs_notes = design_crs(store, file, text)
    for note in (*rec.notes, *crs_notes):
        say(f"{file}: note: {note}")
    result(f"{file}: alignment {rec.name!r}, {rec.element_count} elements, chainage "
           f"{rec.chainage_start_m:.3f} .. {rec.chainage_end_m:.3f} m"
           + (f", {len(rec.notes)} note(s)" if rec.notes else ""), json_output)
    if json_output:
        jsonout.echo({"file": file, "name": rec.name, "elements": rec.element_count,
                      "chainage_start_m": rec.chainage_start_m, "chainage_end_m": rec.chainage_end_m,
                      "notes": list(rec.notes), "crs_notes": list(crs_notes)})


@project_app.command("import-session")
def import_session(
    folder: Annotated[Path, typer.Argument(help="raw session folder (FORMATS.md section 1)")],
    project: ProjectOption,
    session: Annotated[str | None, typer.Option("--session", help="session name (default: the folder name)")] = None,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Import a raw session folder into the project store (one transaction)."""
    from survey.sessionio import SessionFormatError, read_session
    from survey.store import StoreError, alignment_record_from_text

    name = session or folder.resolve().name
    try:
        raw = read_session(folder)
    except SessionFormatError as e:
        fail(str(e))            # names the file inside the folder (folder/fixes.csv: row ...)
    toml_text = (folder / "session.toml").read_text(encoding="utf-8")
    design = None
    if raw.meta.design_alignment is not None:
        path = folder / raw.meta.design_alignment
        try:
            design = alignment_record_from_text(raw.meta.design_alignment, path.read_bytes().decode("utf-8"),
                                                raw.meta.trolley.rail_spacing_m, raw.meta.design_alignment_name)
        except OSError as e:
            fail(f"{path}: {e.strerror or e}")
        except ValueError as e:  # UnicodeDecodeError and LandXmlError
            fail(f"{path}: {e}")
    with _open(root, project) as store:
        try:
            rec = store.import_raw_session(name, raw, design=design, source_toml=toml_text)
        except StoreError as e:
            fail(str(e))
        counts = {c.table: c.rows for c in store.record_counts(rec.session_id)}
    for note in design.notes if design is not None else ():
        say(f"{folder / raw.meta.design_alignment}: note: {note}")
    say(f"{folder}: session {name!r} imported: {counts['imu_sample']} IMU samples, "
              f"{counts['odometer_sample']} odometer readings, {counts['fix']} fixes, "
              f"{counts['gauge_sample']} gauge readings")
    if json_output:
        jsonout.echo({"folder": folder, "session": name, "records": counts})


@project_app.command("export-session")
def export_session(
    project: ProjectOption,
    session: Annotated[str, typer.Option("--session", help="session name")],
    out: Annotated[Path, typer.Option("--out", help="raw session folder to write (must not exist)")],
    overwrite: Annotated[bool, typer.Option("--overwrite", help="replace an existing folder")] = False,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Write a stored session as a raw session folder (accepted fixes only)."""
    from survey.atomicwrite import MARKER_NAME, OutputError, guard_overwrite
    from survey.sessionio import write_session
    from survey.store import StoreError

    try:
        guard_overwrite(out, "project export-session", overwrite, "--out", force_option="--overwrite")
    except OutputError as e:
        fail(str(e))
    with _open(root, project) as store:
        try:
            raw, design_xml = store.raw_session(session)
        except StoreError as e:
            fail(str(e))
    try:
        write_session(out, raw, design_xml, overwrite=overwrite,
                      extra_files={MARKER_NAME: lambda p: p.write_text("project export-session\n", encoding="utf-8")})
    except (FileExistsError, ValueError) as e:
        fail(str(e))
    say(f"session {session!r} written to {out}")
    if json_output:
        jsonout.echo({"session": session, "out": out})


@project_app.command("set-crs")
def set_crs(
    name: Annotated[str, typer.Argument(help="project name")],
    crs: Annotated[str, typer.Argument(help="coordinate reference system of the grid E, N: an EPSG code "
                                            "(EPSG:32650), a compound one (EPSG:25832+5783) or a PROJ string")],
    vertical_datum: Annotated[str | None, typer.Option(
        "--vertical-datum", help="name of the height datum of H [default: the vertical part of a compound CRS]")] = None,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Set the project's CRS and vertical datum. The site latitude, grid convergence and scale
    factor follow from it at the CPIII centroid (trolley/projection.py)."""
    from trolley.projection import CrsError, crs_info

    try:
        info = crs_info(crs)
    except CrsError as e:
        fail(f"CRS: {e}")
    vd = vertical_datum if vertical_datum is not None else (info.vertical_datum or None)
    if vd is not None and not vd.strip():
        fail("--vertical-datum: empty name")
    if vd is not None and any(ord(ch) < 32 or ord(ch) == 127 for ch in vd):
        fail("--vertical-datum: control characters (tab, newline, ...) are not allowed")
    with _open(root, name) as store:
        try:
            grid = apply_crs(store, info, vd)
        except CrsError as e:
            fail(f"CRS {info.text} at the CPIII centroid: {e}")
    say_crs(f"project {name}", info, vd, grid)
    if json_output:
        jsonout.echo({"project": name, "crs": info.text, "crs_name": info.name, "vertical_datum": vd,
                      "cpiii_centroid": grid})


def apply_crs(store, info, vertical_datum: str | None):
    """Make ``info`` (``trolley.projection.CrsInfo``) the project's CRS and ``vertical_datum`` its
    height datum; the settings' latitude becomes the CRS's at the CPIII centroid. Returns the grid
    factors there (``GridFactors``), or None without CPIII points.

    Raises
    ------
    trolley.projection.CrsError
        The CPIII centroid lies outside the CRS's domain (nothing is stored).
    """
    import dataclasses

    import numpy as np

    from trolley.projection import site_factors

    settings = dataclasses.replace(store.settings(), crs=info.text, vertical_datum=vertical_datum)
    pts = store.cpiii_points()
    grid = None
    if pts:
        grid = site_factors(info.text, np.array([[p.e_m, p.n_m, p.h_m] for p in pts]))
        settings = dataclasses.replace(settings, latitude_rad=grid.latitude_rad)
    store.set_settings(settings)
    return grid


def say_crs(who: str, info, vertical_datum: str | None, grid) -> None:
    """The CRS now in force and its factors at the CPIII centroid, on stderr."""
    from trolley import units

    say(f"{who}: CRS {info.text} ({info.name}), vertical datum {vertical_datum or 'not given'}")
    if grid is None:
        say("  no CPIII points yet: the site latitude, convergence and scale follow from them once imported")
    else:
        say(f"  at the CPIII centroid: latitude {units.rad_to_deg(grid.latitude_rad):.6f} deg, longitude "
            f"{units.rad_to_deg(grid.longitude_rad):.6f} deg, grid convergence {units.rad_to_deg(grid.convergence_rad):+.6f} deg, "
            f"point scale {grid.point_scale:.9f}, height reduction {grid.height_reduction:.9f}, "
            f"combined scale {grid.combined_scale:.9f}")


def design_crs(store, file, text: str) -> list[str]:
    """Read the design's LandXML ``<CoordinateSystem>`` (``trolley.landxml.coordinate_system``).

    A project without a CRS takes the file's (an EPSG code, WKT or PROJ string that pyproj knows),
    with its vertical datum; a project whose CRS differs keeps its own. Returns the notes to print
    (what was taken, or why not).
    """
    from trolley.landxml import coordinate_system
    from trolley.projection import CrsError, crs_info, same_crs

    try:
        cs = coordinate_system(text)
    except ValueError as e:
        return [f"<CoordinateSystem> not read: {e}"]
    if cs is None:
        return []
    label = cs.name or cs.horizontal_crs_name or "(no name)"
    if cs.crs_text is None:
        return [f"<CoordinateSystem> {label!r} gives no epsgCode and no WKT or PROJ definition: the project CRS "
                f"is {store.settings().crs or 'not set'} (trolley project set-crs)"]
    try:
        info = crs_info(cs.crs_text)
    except CrsError as e:
        return [f"<CoordinateSystem> {label!r}: {e}; the project CRS is unchanged"]
    current = store.settings().crs
    if current:
        if same_crs(current, info.text):
            return []
        return [f"<CoordinateSystem> {info.text} ({info.name}) differs from the project's CRS {current}: the project "
                "keeps its own (trolley project set-crs to change it)"]
    vd = cs.vertical_datum or cs.vertical_crs_name or info.vertical_datum or None
    try:
        grid = apply_crs(store, info, vd)
    except CrsError as e:
        return [f"<CoordinateSystem> {info.text}: at the CPIII centroid: {e}; the project CRS is unchanged"]
    say_crs(f"{file}: <CoordinateSystem>", info, vd, grid)
    return [f"the project's CRS is now {info.text} from the file's <CoordinateSystem>"]


@project_app.command("set", context_settings={"ignore_unknown_options": True})  # a value "-5" (°C)
def set_field(
    key: Annotated[str, typer.Argument(metavar="KEY", help=(
        "header field: line, track, client, crew, totalstation, totalstation_serial, totalstation_calibrated, "
        "imu, imu_serial, imu_calibrated, trolley, trolley_serial, trolley_calibrated, rail_temperature_c "
        "(checked by the store, which holds the one list; the CRS: `project set-crs`); or a prism constant: "
        "cpiii_prism_constant_mm, trolley_prism_constant_mm"))],
    value: Annotated[str, typer.Argument(help="the value (dates as YYYY-MM-DD, temperature in °C, prism constants "
                                              "in mm, Leica's convention); \"\" clears a header field")],
    project: ProjectOption = ...,
    root: RootOption = Path("projects"),
    json_output: JsonFlag = False,
) -> None:
    """Set a survey header field shown on every sheet and on the PDF report (`trolley project show` lists them),
    or the prism constant the session sets the total station to for the CPIII prisms or the trolley prism."""
    from survey.commands.simulate import PRISM_CONSTANT_KEYS

    if key in PRISM_CONSTANT_KEYS:
        _set_prism_constant(key, value, project, root, json_output)
        return
    from survey.surveyheader import HEADER_FIELDS

    with _open(root, project) as store:
        try:
            text = store.set_header(key, value)
        except ValueError as e:
            fail(str(e))
    label = HEADER_FIELDS[key].label
    say(f"{label}: {text}" if text else f"{label}: cleared (not given)")
    if json_output:
        jsonout.echo({"project": project, "key": key, "label": label, "value": text or None})


def _set_prism_constant(key: str, value: str, project: str, root: Path, json_output: bool) -> None:
    """``project set cpiii_prism_constant_mm|trolley_prism_constant_mm VALUE``: checked as project.toml's
    [totalstation] keys are; the sessions started from now on use it (one already running keeps its own)."""
    import dataclasses

    from survey.commands.simulate import PRISM_CONSTANT_KEYS, prism_constant_m
    from trolley import units

    try:
        value_mm = float(value)
    except ValueError:
        fail(f"{key}: must be a number in mm, got {value!r}")
    try:
        constant_m = prism_constant_m(value_mm, key)
    except ValueError as e:
        fail(str(e))
    with _open(root, project) as store:
        store.set_settings(dataclasses.replace(store.settings(), **{PRISM_CONSTANT_KEYS[key]: constant_m}))
    say(f"{key}: {units.m_to_mm(constant_m):+.1f} mm (the total station is set to it before each measurement "
        "of that prism and read back)")
    if json_output:
        jsonout.echo({"project": project, "key": key, "value_mm": units.m_to_mm(constant_m)})


@project_app.command("show")
def show(
    name: Annotated[str, typer.Argument(help="project name")],
    root: RootOption = Path("projects"),
    as_json: JsonFlag = False,
) -> None:
    """Show a project: settings, CPIII points, design alignment, sessions."""
    import numpy as np
    from rich.table import Table

    from survey.store import settings_to_json
    from trolley import units

    with _open(root, name) as store:
        info = store.info()
        s = store.settings()
        pts = store.cpiii_points()
        al = store.alignment()
        header = store.header()
        grid, grid_problem = None, None
        if s.crs:
            from trolley.projection import CrsError

            try:
                grid = store.site_grid()
            except CrsError as e:      # show what is there, and what is wrong with it
                grid_problem = f"no grid factors at the CPIII: {e}"
        sessions = []
        for rec in store.sessions():
            counts = {c.table: c.rows for c in store.record_counts(rec.session_id)}
            fixes = store.fixes(rec.session_id)
            sessions.append((rec, counts, sum(f.accepted for f in fixes), len(fixes),
                             len(store.station_setups(rec.session_id))))
    enh = np.array([[p.e_m, p.n_m, p.h_m] for p in pts]).reshape(-1, 3)
    arcsec = units.arcsec_to_rad(1.0)

    if as_json:
        doc = {
            "name": info.name, "path": str(info.path), "created_utc": info.created_utc,
            "schema_version": info.schema_version,
            "settings": json.loads(settings_to_json(s)),
            "header": header,
            "grid_problem": grid_problem,
            "grid": None if grid is None else {
                "latitude_deg": units.rad_to_deg(grid.latitude_rad), "longitude_deg": units.rad_to_deg(grid.longitude_rad),
                "convergence_deg": units.rad_to_deg(grid.convergence_rad), "point_scale": grid.point_scale,
                "height_reduction": grid.height_reduction, "combined_scale": grid.combined_scale},
            "cpiii": {"count": len(pts), "min_enh_m": enh.min(axis=0).tolist() if len(pts) else None,
                      "max_enh_m": enh.max(axis=0).tolist() if len(pts) else None},
            "alignment": None if al is None else {"name": al.name, "file": al.file_name, "elements": al.element_count,
                                                  "chainage_start_m": al.chainage_start_m,
                                                  "chainage_end_m": al.chainage_end_m},
            "sessions": [{"name": r.name, "state": r.state, "source": r.source, "created_utc": r.created_utc,
                          "imu_samples": c["imu_sample"], "fixes_accepted": a, "fixes": n, "setups": k}
                         for r, c, a, n, k in sessions],
        }
        jsonout.echo(doc, indent=2)
        return

    out = Console()
    t = Table(title=f"project {escape(info.name)}", show_header=False)
    t.add_column("what")
    t.add_column("value")
    t.add_row("store", f"{escape(str(info.path))} (schema v{info.schema_version}, created {info.created_utc})")
    # with a CRS and CPIII the sessions take the latitude from the grid (store.session_meta)
    lat = grid.latitude_rad if grid is not None else s.latitude_rad
    t.add_row("site", f"latitude {units.rad_to_deg(lat):.4f} deg"
                      + (" (the CRS's at the CPIII centroid)" if grid is not None else "")
                      + f", height {s.height_m:.1f} m")
    if s.crs:
        g = grid
        t.add_row("CRS", f"{escape(str(s.crs))}, vertical datum {escape(str(s.vertical_datum or 'not given'))}" + (
            f"; at the CPIII: convergence {units.rad_to_deg(g.convergence_rad):+.6f} deg, "
            f"combined scale {g.combined_scale:.9f}" if g is not None else "")
            + (f"; {escape(grid_problem)}" if grid_problem else ""))
    t.add_row("IMU", f"{escape(s.imu.name)}: bias instability {units.rad_s_to_deg_h(s.imu.gyro_bias_instability_rad_s):.3g} deg/h, "
                     f"ARW {units.rad_sqrt_s_to_deg_sqrt_h(s.imu.gyro_arw_rad_sqrt_s):.3g} deg/sqrt(h), "
                     f"accel bias {units.m_s2_to_ug(s.imu.accel_bias_m_s2):.0f} ug")
    la = units.m_to_mm(np.asarray(s.trolley.prism_lever_arm_m))
    t.add_row("trolley", f"prism lever arm [{la[0]:.0f}, {la[1]:.0f}, {la[2]:.0f}] mm (FRD), rail spacing "
                         f"{units.m_to_mm(s.trolley.rail_spacing_m):.0f} mm, nominal gauge "
                         f"{units.m_to_mm(s.trolley.nominal_gauge_m):.0f} mm")
    t.add_row("total station", f"direction {s.instrument.direction_rad / arcsec:.2g}\", zenith "
                               f"{s.instrument.zenith_rad / arcsec:.2g}\", distance "
                               f"{units.m_to_mm(s.instrument.distance_m):.2g} mm + {s.instrument.distance_scale * 1e6:.2g} ppm; "
                               f"fix sigma {units.m_to_mm(s.fix_sigma_m):.2g} mm; prism constant CPIII "
                               f"{units.m_to_mm(s.cpiii_prism_constant_m):+.1f} mm, trolley "
                               f"{units.m_to_mm(s.trolley_prism_constant_m):+.1f} mm")
    pm = s.polar_model
    t.add_row("polar model", (f"curvature and refraction k = {pm.refraction_k:g}" if pm.curvature_refraction
                              else "no curvature/refraction") + f", grid scale {pm.grid_scale:.8f}")
    t.add_row("resection tolerance", f"|w| <= {s.max_standardized_residual:g}, residual <= "
                                     f"{units.m_to_mm(s.max_point_residual_m):g} mm, overlap <= "
                                     f"{units.m_to_mm(s.overlap_tolerance_m):g} mm")
    t.add_row("conventions", f"signs {s.sign_convention}, tolerance set {escape(str(s.tolerance_set))}, "
                             f"static alignment {s.static_s:.0f} s")
    if pts:
        lo, hi = enh.min(axis=0), enh.max(axis=0)
        t.add_row("CPIII", f"{len(pts)} points: E {lo[0]:.3f} .. {hi[0]:.3f}, N {lo[1]:.3f} .. {hi[1]:.3f}, "
                           f"H {lo[2]:.3f} .. {hi[2]:.3f} m")
    else:
        t.add_row("CPIII", "none (trolley project import-cpiii FILE --project NAME)")
    if al is not None:
        t.add_row("alignment", f"{escape(str(al.name))} ({escape(str(al.file_name))}): {al.element_count} elements, chainage "
                               f"{al.chainage_start_m:.3f} .. {al.chainage_end_m:.3f} m")
    else:
        t.add_row("alignment", "none (trolley project import-alignment FILE.xml --project NAME)")
    from survey.surveyheader import HEADER_FIELDS, NOT_GIVEN

    for key, fld in HEADER_FIELDS.items():
        t.add_row(f"{fld.label} ({key})", header.get(key, NOT_GIVEN))
    out.print(t)
    st = Table(title="sessions")
    for col in ("name", "state", "source", "created (UTC)", "IMU samples", "fixes accepted/all", "setups"):
        st.add_column(col)
    for r, c, a, n, k in sessions:
        st.add_row(escape(r.name), r.state, escape(str(r.source)), r.created_utc, str(c["imu_sample"]), f"{a}/{n}", str(k))
    if not sessions:
        st.add_row("(none)", "", "", "", "", "", "")
    out.print(st)


def resection_table(result, title: str = "free station"):
    """A rich table of a resection for the crew: station, orientation, sigma0 and per-point residuals.

    Parameters
    ----------
    result : trolley.resection.Resection

    Returns
    -------
    rich.table.Table with residuals in mm (across / along / height) and arc seconds, the largest
    standardized residual |w| of each point, and flagged points in red with the reason.
    """
    import numpy as np
    from rich.table import Table

    from trolley import units
    from trolley.resection import variance_factor

    arcsec = units.arcsec_to_rad(1.0)
    # the sigmas the fixes will carry: scaled by sigma0 when it is above 1 (Resection.setup_covariance)
    sig_all = np.sqrt(np.diag(result.setup_covariance))
    sig = units.m_to_mm(sig_all[:3])
    e, n, h = result.station_enh_m
    scaled = variance_factor(result.sigma0, result.dof) > 1.0
    caption = (f"station E {e:.4f} N {n:.4f} H {h:.4f} m (1-sigma {sig[0]:.2f} / {sig[1]:.2f} / {sig[2]:.2f} mm), "
               f"orientation {units.rad_to_deg(result.orientation_rad):.6f} deg "
               f"(1-sigma {sig_all[3] / arcsec:.2f}\"), sigma0 {result.sigma0:.2f} ({result.dof} dof)"
               + ("; the 1-sigmas are scaled by sigma0" if scaled else ""))
    if result.excluded:
        caption += f"; dropped: {escape(', '.join(map(str, result.excluded)))}"
    t = Table(title=title, caption=caption)
    for col in ("point", "across mm", "along mm", "height mm", "hz \"", "zenith \"", "dist mm", "|w| max", "flag"):
        t.add_column(col, justify="left" if col in ("point", "flag") else "right")

    def fmt(x: float, scale: float, digits: int = 2) -> str:
        return "-" if not np.isfinite(x) else f"{x * scale:+.{digits}f}"

    from trolley.resection import suggest_point_to_drop

    worst = suggest_point_to_drop(result)
    if worst is not None:
        caption += f"; data snooping suggests dropping or re-measuring {escape(str(worst))} (one point at a time)"
        t.caption = caption
    mm = units.m_to_mm(1.0)
    for r in result.residuals:
        style = "bold red" if r.point_id == worst else ("yellow" if r.flagged else None)
        t.add_row(escape(str(r.point_id)), fmt(r.across_m, mm), fmt(r.along_m, mm), fmt(r.height_m, mm),
                  fmt(r.hz_rad, 1 / arcsec, 1), fmt(r.zenith_rad, 1 / arcsec, 1), fmt(r.distance_m, mm),
                  "-" if not np.isfinite(r.max_standardized) else f"{r.max_standardized:.1f}",
                  escape(str(r.reason)) if r.flagged else "ok", style=style)
    return t


def register(app: typer.Typer) -> None:
    """Add the ``project`` command group to the trolley app."""
    app.add_typer(project_app, name="project")
