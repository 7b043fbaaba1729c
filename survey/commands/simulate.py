"""``trolley simulate``: write a simulated raw session folder (FORMATS.md sec. 1) plus truth.csv.

The settings come from the project's ``project.toml`` (``[site]``, ``[imu] preset``,
``[trolley]``, ``[simulation]``; see docs/simulator.md) and the design from the LandXML file it
names; command-line options override them. Machine output (a JSON summary) goes to stdout,
progress and errors to stderr.
"""
from __future__ import annotations

import math

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from survey.commands.options import ImuPreset, JsonAlways
from survey.limits import check_allocation, check_seed
from survey.names import inside
from rich.markup import escape

_REPO_DEMO = Path(__file__).resolve().parents[2] / "projects" / "demo"

#: project.toml [simulation] keys -> SimulationConfig fields (all floats unless listed)
_SIM_KEYS = ("length_m", "start_chainage_m", "fix_spacing_m", "stop_s", "static_s", "speed_m_s",
             "accel_time_s", "imu_rate_hz", "odometer_rate_hz", "gauge_rate_hz", "fix_sigma_m",
             "gauge_sigma_m", "irregularity_rms_m", "imu_residual_misalignment_rad",
             "gyro_correlation_time_s", "turn_s", "lift_tilt_rad", "placement_offset_m")
_SIM_INT_KEYS = ("seed", "fixes_per_stop")
#: largest --site-east-m, m: a tenth of the grid coordinates `trolley process` accepts (sessionio.PLAUSIBLE_ABS)
SITE_EAST_LIMIT_M = 1e7
_SIM_INT_LIST_KEYS = ("turn_at_stops", "lift_at_stops")


class ProjectFileError(ValueError):
    """A bad project.toml; the message names the file and the key."""


#: [simulation] keys that must be > 0, and those that must be >= 0 (the others: any finite number)
_SIM_POSITIVE = frozenset({"length_m", "fix_spacing_m", "speed_m_s", "accel_time_s", "imu_rate_hz", "fixes_per_stop",
                           "odometer_rate_hz", "gauge_rate_hz", "gyro_correlation_time_s", "turn_s"})
_SIM_NON_NEGATIVE = frozenset({"stop_s", "static_s", "fix_sigma_m", "gauge_sigma_m", "irregularity_rms_m",
                               "imu_residual_misalignment_rad", "lift_tilt_rad", "seed"})
#: shortest simulated survey, m
MIN_SIMULATED_LENGTH_M = 1.0
#: longest fix spacing, m: the accuracy budget's range (survey.commands.budget.RANGES); 1e300
#: simulated a survey with a fix at either end only
MAX_FIX_SPACING_M = 10000.0
#: coarsest truth.csv step, m
MAX_TRUTH_STEP_M = 5.0
#: plausible site heights, m (ellipsoidal or orthometric: the Dead Sea shore to above any railway)
SITE_HEIGHT_RANGE_M = (-1000.0, 10000.0)
#: prism constants a project may give, mm (Leica's convention): the prisms in use lie within
#: -34.4..+34.4 (docs/field_session.md, "Prism constants"); beyond 100 mm it is a typo or metres
PRISM_CONSTANT_RANGE_MM = (-100.0, 100.0)
#: [totalstation] keys of project.toml -> ProjectSettings fields (SI)
PRISM_CONSTANT_KEYS = {"cpiii_prism_constant_mm": "cpiii_prism_constant_m",
                       "trolley_prism_constant_mm": "trolley_prism_constant_m"}


def _number(data: dict, table: str, key: str, fname: str, integer: bool = False):
    """A finite number (an integer with ``integer``), >= 0 or > 0 where the key needs it: a value
    the session cannot use is refused when the project is made, not after the crew's work."""
    import math

    v = data[key]
    ok = isinstance(v, int) if integer else isinstance(v, (int, float))
    if isinstance(v, bool) or not ok or not math.isfinite(v):
        kind = "an integer" if integer else "a finite number"
        raise ProjectFileError(f"{fname}: key {table}.{key}: must be {kind}, got {v!r}")
    if (key in _SIM_POSITIVE or (table == "trolley")) and not v > 0:
        raise ProjectFileError(f"{fname}: key {table}.{key}: must be > 0, got {v!r}")
    if key in _SIM_NON_NEGATIVE and v < 0:
        raise ProjectFileError(f"{fname}: key {table}.{key}: must be >= 0, got {v!r}")
    if (table, key) == ("site", "latitude_deg"):
        from trolley.earth import MAX_LATITUDE_DEG

        if abs(v) > MAX_LATITUDE_DEG:
            raise ProjectFileError(f"{fname}: key site.latitude_deg: must be within -{MAX_LATITUDE_DEG:g}.."
                                   f"{MAX_LATITUDE_DEG:g} (no north-seeking alignment near the poles), got {v!r}")
    if (table, key) == ("site", "height_m") and not SITE_HEIGHT_RANGE_M[0] <= v <= SITE_HEIGHT_RANGE_M[1]:
        raise ProjectFileError(f"{fname}: key site.height_m: must be within {SITE_HEIGHT_RANGE_M[0]:g}.."
                               f"{SITE_HEIGHT_RANGE_M[1]:g} m, got {v!r}")
    return int(v) if integer else float(v)


def prism_constant_m(value_mm: float, where: str) -> float:
    """A prism constant given in mm (project.toml, ``project set``), checked, in m.

    Raises
    ------
    ValueError
        naming ``where``: not finite, or outside :data:`PRISM_CONSTANT_RANGE_MM`.
    """
    from survey.limits import check_finite
    from trolley import units

    check_finite(value_mm, where, minimum=PRISM_CONSTANT_RANGE_MM[0], maximum=PRISM_CONSTANT_RANGE_MM[1],
                 why="mm, Leica's convention: round prism 0.0, 360° prism +23.1")
    return float(units.mm_to_m(value_mm))


def simulation_kwargs(kwargs: dict) -> dict:
    """The SimulationConfig keyword arguments among ``kwargs`` (the project-only settings, such as
    the prism constants, left out)."""
    from dataclasses import fields

    from trolley.truthsim import SimulationConfig

    names = {f.name for f in fields(SimulationConfig)}
    return {k: v for k, v in kwargs.items() if k in names}


def project_settings(project: Path, project_keys: bool = False):
    """Simulation settings and design text of a project folder.

    Parameters
    ----------
    project : folder with ``project.toml`` and the design it names.
    project_keys : also return the settings of the project that the simulation does not take (the
        prism constants of ``[totalstation]``; ``project new`` stores them).

    Returns
    -------
    (dict, str, str)
        SimulationConfig keyword arguments (SI; with ``project_keys`` the ProjectSettings ones
        too), the IMU preset name, the LandXML text.

    Raises
    ------
    ProjectFileError
        Missing or malformed file or key (the message names the file and key).
    """
    import tomllib

    import numpy as np

    from trolley import units
    from trolley.session import TrolleyGeometry

    path = project / "project.toml"
    fname = str(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ProjectFileError(f"{fname}: file missing") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProjectFileError(f"{fname}: not valid TOML: {exc}") from None
    kwargs: dict = {}
    site = data.get("site", {})
    if "latitude_deg" in site:
        kwargs["latitude_rad"] = float(units.deg_to_rad(
            _number(site, "site", "latitude_deg", fname)))
    if "height_m" in site:
        kwargs["height_m"] = _number(site, "site", "height_m", fname)
    if "crs" in site:
        if not isinstance(site["crs"], str):
            raise ProjectFileError(f"{fname}: key site.crs: must be a string, got {site['crs']!r}")
        kwargs["crs"] = site["crs"]
    ts = data.get("totalstation", {})
    if not isinstance(ts, dict):
        raise ProjectFileError(f"{fname}: key totalstation: must be a table ([totalstation])")
    for key in ts:
        if key not in PRISM_CONSTANT_KEYS:
            raise ProjectFileError(f"{fname}: key totalstation.{key}: unknown setting (the keys are "
                                   f"{', '.join(PRISM_CONSTANT_KEYS)})")
        try:
            kwargs[PRISM_CONSTANT_KEYS[key]] = prism_constant_m(_number(ts, "totalstation", key, fname),
                                                                f"{fname}: key totalstation.{key}")
        except ValueError as exc:
            raise ProjectFileError(str(exc)) from None
    sim = data.get("simulation", {})
    for key in sim:
        if key in _SIM_KEYS:
            kwargs[key] = _number(sim, "simulation", key, fname)
        elif key in _SIM_INT_KEYS:
            kwargs[key] = _number(sim, "simulation", key, fname, integer=True)
        elif key in _SIM_INT_LIST_KEYS:
            v = sim[key]
            if not (isinstance(v, list) and all(isinstance(x, int) and not isinstance(x, bool) for x in v)):
                raise ProjectFileError(f"{fname}: key simulation.{key}: must be a list of integers, got {v!r}")
            kwargs[key] = tuple(v)
        else:
            raise ProjectFileError(f"{fname}: key simulation.{key}: unknown setting")
    tr = data.get("trolley", {})
    if tr:
        d = TrolleyGeometry()
        vec = {}
        for key in ("prism_lever_arm_m", "imu_misalignment_rad"):
            if key in tr:
                v = tr[key]
                if not (isinstance(v, list) and len(v) == 3 and all(
                        isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)):
                    raise ProjectFileError(f"{fname}: key trolley.{key}: must be 3 finite numbers")
                from survey.sessionio import MAX_LEVER_ARM_M, MAX_MISALIGNMENT_RAD

                limit = MAX_LEVER_ARM_M if key == "prism_lever_arm_m" else MAX_MISALIGNMENT_RAD
                if max(abs(float(x)) for x in v) > limit:
                    raise ProjectFileError(f"{fname}: key trolley.{key}: each component must be within +-{limit:g} "
                                           f"({'m' if key == 'prism_lever_arm_m' else 'rad'}), got {v!r}")
                vec[key] = np.array(v, dtype=float)
        kwargs["trolley"] = TrolleyGeometry(
            prism_lever_arm_m=vec.get("prism_lever_arm_m", d.prism_lever_arm_m),
            imu_misalignment_rad=vec.get("imu_misalignment_rad", d.imu_misalignment_rad),
            rail_spacing_m=_number(tr, "trolley", "rail_spacing_m", fname)
            if "rail_spacing_m" in tr else d.rail_spacing_m,
            nominal_gauge_m=_number(tr, "trolley", "nominal_gauge_m", fname)
            if "nominal_gauge_m" in tr else d.nominal_gauge_m)
    from trolley.landxml import LandXmlError, decoded_landxml

    preset = data.get("imu", {}).get("preset", "rlg")
    design = data.get("design", {}).get("alignment")
    if not isinstance(design, str):
        raise ProjectFileError(f"{fname}: key design.alignment: missing (the LandXML design)")
    try:
        xml = decoded_landxml(inside(project, design, f"{fname}: key design.alignment").read_bytes())
    except FileNotFoundError:
        raise ProjectFileError(f"{fname}: key design.alignment: {project / design} not found") \
            from None
    except IsADirectoryError:
        raise ProjectFileError(f"{fname}: key design.alignment: {design!r} is a folder, not the LandXML file") from None
    except LandXmlError as exc:
        raise ProjectFileError(f"{fname}: key design.alignment: {project / design}: {exc}") from None
    except ValueError as exc:
        raise ProjectFileError(str(exc)) from None
    return (kwargs if project_keys else simulation_kwargs(kwargs)), preset, xml


def _file_or_option(key: str) -> str:
    """The option that sets a SimulationConfig field (the same key of project.toml's [simulation])."""
    return {"imu_rate_hz": "--rate-hz"}.get(key, "--" + key.replace("_", "-")) + f" / project.toml simulation.{key}"


#: Memory one simulated IMU sample needs through the simulation and the writing (truth states,
#: the six channels, noise, CSV text), bytes; one truth.csv row likewise.
_SAMPLE_BYTES = 1024
_TRUTH_ROW_BYTES = 256


def check_simulation_size(config, truth_step_m: float) -> None:
    """Refuse a simulation whose arrays would not fit in memory, before it starts.

    The duration is the static period, the stops and the runs between them; every sensor
    sample and every truth.csv row is counted (:func:`survey.limits.check_allocation`).
    """
    stops = config.length_m / config.fix_spacing_m + 1
    duration_s = (config.static_s + stops * (config.stop_s + config.accel_time_s)
                  + config.length_m / config.speed_m_s)
    rates = config.imu_rate_hz + config.odometer_rate_hz + config.gauge_rate_hz
    check_allocation(duration_s * rates, _SAMPLE_BYTES,
                     f"--rate-hz {config.imu_rate_hz:g} over {duration_s:.4g} s (--length-m, --static-s, "
                     f"--fix-spacing-m)")
    check_allocation(config.length_m / truth_step_m, _TRUTH_ROW_BYTES,
                     f"--truth-step-m {truth_step_m:g} over {config.length_m:g} m")


def register(app: typer.Typer) -> None:
    """Add ``trolley simulate`` to the app."""

    @app.command("simulate")
    def simulate(
        out: Annotated[Path, typer.Option("--out", help="session folder to write (must not exist "
                                                        "unless --force)")],
        project: Annotated[Path, typer.Option(help="project folder with project.toml and the "
                                                   "design")] = Path("projects/demo"),
        length_m: Annotated[Optional[float], typer.Option("--length-m", help="surveyed length, m")] = None,
        imu: Annotated[Optional[ImuPreset], typer.Option(help="IMU grade (default: the project's)")] = None,
        seed: Annotated[Optional[int], typer.Option(help="random seed")] = None,
        track_seed: Annotated[Optional[int], typer.Option(
            "--track-seed", help="seed of the track's irregularities alone (default: drawn with --seed); one "
                                 "--track-seed with two --seed values is a repeat survey of one track "
                                 "(`trolley compare`)")] = None,
        fix_spacing_m: Annotated[Optional[float], typer.Option("--fix-spacing-m",
                                                               help="stop spacing, m")] = None,
        static_s: Annotated[Optional[float], typer.Option("--static-s",
                                                          help="initial static period, s")] = None,
        rate_hz: Annotated[Optional[float], typer.Option("--rate-hz", help="IMU rate, Hz")] = None,
        step_m: Annotated[float, typer.Option("--truth-step-m", help="truth.csv chainage step, m")] = 0.1,
        turn_at_stop: Annotated[Optional[list[int]], typer.Option(
            "--turn-at-stop", help="the crew turns the trolley around at this stop (1 = the first "
                                   "after the static alignment); repeat for more")] = None,
        crs: Annotated[Optional[str], typer.Option(
            "--crs", help="project CRS of the design's grid (EPSG code or PROJ string): the IMU sees "
                          "true north and ground distances, the fixes are in this grid")] = None,
        site_east_m: Annotated[float, typer.Option(
            "--site-east-m", help="move the design (and so the site) this far east in the grid, m "
                                  "(e.g. 200000: 200 km off a UTM central meridian)")] = 0.0,
        crs_in_session: Annotated[bool, typer.Option(
            "--crs-in-session/--no-crs-in-session",
            help="write [site] crs to session.toml (off: a crew that did not give it)")] = True,
        force: Annotated[bool, typer.Option("--force", help="replace an existing --out")] = False,
        json_output: JsonAlways = False,
    ) -> None:
        """Simulate a stop-and-go survey (full 3-D truth, strapdown IMU) into a raw session folder."""
        from dataclasses import replace

        from rich.console import Console

        from survey import jsonout
        from survey.atomicwrite import MARKER_NAME, OutputError, guard_overwrite
        from survey.commands.progress import progress_bar, share
        from survey.limits import check_finite
        from survey.sessionio import write_session, write_truth_csv
        from trolley.landxml import parse_landxml
        from trolley.sensors import IMU_PRESETS
        from trolley.truthsim import SimulationConfig, simulate_survey

        err = Console(stderr=True)

        def fail(message: str) -> None:
            err.print(f"error: {message}", highlight=False, soft_wrap=True, markup=False)
            raise typer.Exit(code=2)

        proj = project
        if not (proj / "project.toml").exists() and project == Path("projects/demo"):
            proj = _REPO_DEMO
        try:
            kwargs, preset, xml = project_settings(proj)
        except ProjectFileError as exc:
            fail(str(exc))
        preset = imu or preset
        if preset not in IMU_PRESETS:
            fail(f"--imu: unknown IMU preset {preset!r} (choose {', '.join(IMU_PRESETS)})")
        kwargs["imu"] = IMU_PRESETS[preset]
        for key, value in (("length_m", length_m), ("seed", seed), ("fix_spacing_m", fix_spacing_m),
                           ("static_s", static_s), ("imu_rate_hz", rate_hz)):
            if value is not None:
                kwargs[key] = value
        try:
            check_finite(length_m, "--length-m", minimum=MIN_SIMULATED_LENGTH_M, why="a track between two fixes")
            check_finite(fix_spacing_m, "--fix-spacing-m", positive=True, maximum=MAX_FIX_SPACING_M,
                         why="the longest fix spacing the accuracy budget covers")
            check_finite(rate_hz, "--rate-hz", positive=True)      # (its size is checked below)
            check_finite(step_m, "--truth-step-m", positive=True, maximum=MAX_TRUTH_STEP_M,
                         why="truth.csv samples the track; 1e300 wrote a truth of two rows")
            check_finite(static_s, "--static-s", minimum=0.0)
            check_seed(seed)
            check_seed(track_seed, "--track-seed")
            check_finite(site_east_m, "--site-east-m", minimum=-SITE_EAST_LIMIT_M, maximum=SITE_EAST_LIMIT_M,
                         why="the session's grid coordinates must stay readable by `trolley process`")
            for key in ("length_m", "fix_spacing_m", "imu_rate_hz"):  # from project.toml when not given
                check_finite(kwargs.get(key), f"{_file_or_option(key)}", positive=True)
            config = SimulationConfig(**kwargs)
            # a session `trolley process` can take: a static alignment of enough samples, a track
            from trolley.deadreckoning import MIN_STATIC_SAMPLES

            if config.static_s * config.imu_rate_hz < MIN_STATIC_SAMPLES:
                raise ValueError(f"--static-s {config.static_s:g} at --rate-hz {config.imu_rate_hz:g} gives "
                                 f"{config.static_s * config.imu_rate_hz:.3g} IMU samples standing still; the static "
                                 f"alignment needs at least {MIN_STATIC_SAMPLES}")
            if config.length_m < MIN_SIMULATED_LENGTH_M:
                raise ValueError(f"{_file_or_option('length_m')} must be at least {MIN_SIMULATED_LENGTH_M:g} m (a "
                                 f"track between two fixes), got {config.length_m:g}")
            check_simulation_size(config, step_m)
        except (ValueError, TypeError) as exc:
            fail(str(exc))
        try:
            guard_overwrite(out, "simulate", force)
        except OutputError as exc:
            fail(str(exc))
        try:
            alignment = parse_landxml(xml)
        except ValueError as exc:
            fail(f"{proj}: design: {exc}")
        if turn_at_stop:
            # stops 1..n-1 (stop 0 is the static alignment), n from the interval and the length
            n_stops = int(math.floor(config.length_m / config.fix_spacing_m + 1e-9)) + 1 + (
                config.length_m % config.fix_spacing_m > 1e-6)
            bad = [k for k in turn_at_stop if not 1 <= k <= n_stops - 1]
            if bad:
                fail(f"--turn-at-stop {bad[0]}: the survey has stops 1..{n_stops - 1} (stop 0 is the static "
                     f"alignment; {config.length_m:g} m with a fix every {config.fix_spacing_m:g} m)")
            kwargs["turn_at_stops"] = tuple(turn_at_stop)
        if crs is not None:
            kwargs["crs"] = crs
        if kwargs.get("crs"):
            from trolley.projection import CrsError, crs_info
            try:
                kwargs["crs"] = crs_info(kwargs["crs"]).text
            except CrsError as exc:
                fail(f"--crs: {exc}")
        kwargs["crs_in_session"] = crs_in_session
        if track_seed is not None:
            kwargs["track_seed"] = track_seed
        if site_east_m:
            from trolley.landxml import landxml_text

            alignment = alignment.translated(site_east_m, 0.0)
            rail = kwargs.get("trolley").rail_spacing_m if "trolley" in kwargs else None
            xml = landxml_text(alignment, **({"rail_spacing_m": rail} if rail else {}))
        config = SimulationConfig(**kwargs)  # the turn stops are checked with the motion below
        t0 = time.perf_counter()
        err.print(f"simulating {config.length_m:g} m with the {preset} IMU at "
                  f"{config.imu_rate_hz:g} Hz ...", highlight=False)
        with progress_bar("simulating", console=err) as report:
            try:
                sim = simulate_survey(alignment, config, progress=share(report, 0.0, 0.55))
            except ValueError as exc:
                fail(str(exc))
            t1 = time.perf_counter()
            session = replace(sim.session, meta=replace(sim.session.meta,
                                                        design_alignment="alignment.xml"))
            try:
                write_session(out, session, xml, overwrite=force,
                              extra_files={"truth.csv": lambda p: write_truth_csv(p, sim.truth, step_m),
                                           MARKER_NAME: lambda p: p.write_text("simulate\n", encoding="utf-8")},
                              progress=share(report, 0.55, 1.0))
            except (OSError, ValueError) as exc:
                fail(f"{out}: {exc}")
        t2 = time.perf_counter()
        err.print(f"wrote {escape(str(out))} (simulate {t1 - t0:.1f} s, write {t2 - t1:.1f} s)", highlight=False)
        summary = {
            "out": str(out),
            "imu": preset,
            "length_m": config.length_m,
            "duration_s": sim.truth.motion.duration_s,
            "imu_samples": int(session.imu_t_s.size),
            "odometer_samples": int(session.odo_t_s.size),
            "fixes": int(len(session.fixes)),
            "stops": int(sim.truth.motion.stop_chainage_m.size),
            "seed": config.seed,
            "track_seed": config.track_seed,
            "crs": config.crs,
            "site_east_m": site_east_m,
            "simulate_s": round(t1 - t0, 3),
            "write_s": round(t2 - t1, 3),
        }
        jsonout.echo(summary)
