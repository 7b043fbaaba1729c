"""What the crew sees after each accepted fix: the interval's geometry and its defects.

The stations of the interval just smoothed (``trolley.live.LiveProcessor.smooth_last_interval``)
get the design columns, the track-geometry parameters (``trolley.trackgeometry``) and the check
against the project's tolerance set (``trolley.tolerances``): the same computation as the survey
sheet, on one interval.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from trolley.tolerances import Defect, ToleranceSet, find_defects
from trolley.trackgeometry import TrackGeometry, TrackInput, track_geometry


@dataclass
class IntervalCheck:
    """Geometry and defects of one interval, and how long they took."""

    geometry: TrackGeometry | None
    defects: list[Defect]
    seconds: float


def tolerance_set_name(name: str | None) -> str:
    """The tolerance set a project setting names: "default" (or nothing) is the survey sheet's
    default set; anything else is a built-in set name or a TOML file, used as given."""
    from survey.export import DEFAULT_TOLERANCES

    return DEFAULT_TOLERANCES if name in (None, "", "default") else str(name)


def tolerance_set(name: str | None) -> ToleranceSet:
    """A project's tolerance set (:func:`tolerance_set_name`).

    Raises
    ------
    trolley.tolerances.ToleranceError : unknown name, unreadable or invalid file.
    """
    from survey.tolerance_files import load_tolerances

    return load_tolerances(tolerance_set_name(name))


def interval_check(stations, design, tol: ToleranceSet, rail_spacing_m: float, nominal_gauge_m: float) -> IntervalCheck:
    """Geometry parameters and defects of the stations of one interval.

    Parameters
    ----------
    stations : ``trolley.engine.Stations`` of the interval.
    design : ``trolley.alignment.Alignment`` or None.
    tol : tolerance set.
    rail_spacing_m, nominal_gauge_m : trolley geometry.
    """
    from survey.export import geometry_config
    from survey.track_reader import SurveyInfo

    t0 = time.perf_counter()
    st = stations
    if len(st.chainage_m) < 3:
        return IntervalCheck(None, [], time.perf_counter() - t0)
    track = TrackInput(st.chainage_m, st.E_m, st.N_m, st.H_m, st.sigma_E_m, st.sigma_N_m, st.sigma_H_m,
                       st.lateral_dev_m, st.vertical_dev_m, st.gauge_m, st.cant_m)
    if design is not None:
        d = design.evaluate(track.chainage_m)
        track.design_E_m, track.design_N_m = d.E_m, d.N_m
        track.design_H_m = d.H_m if design.profile is not None else np.full(d.H_m.shape, np.nan)
        track.design_cant_m = rail_spacing_m * np.sin(d.cant_rad)
    cfg = geometry_config(tol, SurveyInfo(rail_spacing_m=rail_spacing_m, nominal_gauge_m=nominal_gauge_m))
    geometry = track_geometry(track, cfg)
    defects = find_defects(geometry.chainage_m, geometry.columns, tol)
    return IntervalCheck(geometry, defects, time.perf_counter() - t0)


def defects_text(check: IntervalCheck, tol: ToleranceSet, station=None) -> str:
    """One line of plain text (it is stored as well as shown): the defects of the interval
    against the tolerance set, at the drawing's stations ``station(chainage)`` when given (the
    design's station equations; ``Alignment.station``), else at the internal chainage."""
    if check.geometry is None:
        return "too short for the geometry check"
    if not check.defects:
        return f"no defects against {tol.name}"
    at = (lambda c: c) if station is None else (lambda c: float(station(np.array([c]))[0]))
    worst = ", ".join(f"{d.parameter} {at(d.start_chainage_m):.1f}-{at(d.end_chainage_m):.1f} m"
                      for d in check.defects[:3])
    more = f" and {len(check.defects) - 3} more" if len(check.defects) > 3 else ""
    return f"{len(check.defects)} defects against {tol.name}: {worst}{more}"
