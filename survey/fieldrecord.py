"""The field record beside a processed track: what the crew decided, for the survey sheet.

``trolley process`` sees only the accepted fixes (the raw session folder holds no others), so a
fix the crew rejected, re-measured or undid, a station setup with its residuals and the overlap
check after a station change would not reach the sheet. At the end of a field session the store's
record of them is written next to ``track.csv`` as ``field_record.json``
(:func:`write_field_record`; FORMATS.md section 2, "field_record.json"); ``trolley export`` reads
it when present (:func:`read_field_record`).

Nothing is recomputed except the overlap checks' differences and their covariances, which the
session computed from the same two stored fixes and their stored setups
(``trolley.resection.overlap_check``: new minus old station, each fix's covariance holding its
measurement and its setup, on the sigmas it is stored with, :func:`stored_fix_covariance`) and did
not keep apart from the fix's reason; :func:`overlap_checks` pairs each overlap fix with the fix taken just before it from
the previous station, exactly as the session did.

No paper section: record keeping (DESIGN.md, "nothing lost").
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from survey.track_reader import ExportInputError

#: file name beside track.csv
FIELD_RECORD = "field_record.json"
#: ``format`` value of the file
FORMAT = "trolley-field-record/1"
#: reason prefix of a fix measured from a new station at the stop of the previous fix
OVERLAP_PREFIX = "overlap check"


@dataclass(frozen=True)
class RecordFix:
    """A prism fix as the crew took it, with its newest decision (SI)."""

    t_s: float
    point: str
    E_m: float
    N_m: float
    H_m: float
    station: int
    accepted: bool
    reason: str
    sigma_E_m: float = math.nan  # as stored: the measurement and the setup carried to the fix
    sigma_N_m: float = math.nan
    sigma_H_m: float = math.nan


@dataclass(frozen=True)
class RecordPointing:
    """One CPIII pointing of a station setup with its residuals (SI; NaN where not used)."""

    point: str
    used: bool
    across_m: float
    along_m: float
    height_m: float
    hz_rad: float
    zenith_rad: float
    distance_m: float
    max_standardized: float
    flagged: bool
    reason: str


@dataclass(frozen=True)
class RecordSetup:
    """A free-station setup (station numbered from 1 in the order they were set up)."""

    station: int
    t_s: float
    E_m: float
    N_m: float
    H_m: float
    orientation_rad: float
    sigma0: float
    dof: int
    accepted: bool
    excluded: tuple[str, ...]
    pointings: tuple[RecordPointing, ...]


@dataclass(frozen=True)
class RecordOverlap:
    """An overlap check: the trolley prism at one stop measured from the old and the new station.

    ``sigma_dE_m`` .. ``sigma_dH_m`` are the 1-sigma of the difference per axis (both fixes'
    measurements and setups), ``max_d_over_sigma`` the largest |difference| / sigma (for display),
    ``mahalanobis`` the difference's length in its joint sigma sqrt(d' C^-1 d) (E-N-H correlations
    included), ``consistent`` whether that is within ``sigma_limit`` (None, and NaN sigmas, for fixes
    stored without sigmas; records before the joint test hold no ``mahalanobis`` and a per-axis
    ``sigma_limit`` of 3).
    """

    t_s: float
    old_point: str
    new_point: str
    from_station: int
    to_station: int
    dE_m: float
    dN_m: float
    dH_m: float
    tolerance_m: float
    within: bool
    accepted: bool
    reason: str
    sigma_dE_m: float = math.nan
    sigma_dN_m: float = math.nan
    sigma_dH_m: float = math.nan
    max_d_over_sigma: float = math.nan
    sigma_limit: float = math.nan
    consistent: bool | None = None
    mahalanobis: float = math.nan

    @property
    def limit_text(self) -> str:
        """The bound the difference was tested against: "3.44 joint sigma" (a record before the
        joint test: "3 sigma", per axis)."""
        return (f"{self.sigma_limit:.2f} joint sigma" if math.isfinite(self.mahalanobis)
                else f"{self.sigma_limit:g} sigma")

    @property
    def sigma_verdict(self) -> str:
        """The verdict against the sigma for the sheet and the report: "within 3.44 joint sigma
        (2.71)", "BEYOND ...", or "not known" (fixes stored without sigmas)."""
        if self.consistent is None:
            return "not known"
        joint = f" ({self.mahalanobis:.2f})" if math.isfinite(self.mahalanobis) else ""
        return f"{'within' if self.consistent else 'BEYOND'} {self.limit_text}{joint}"


@dataclass(frozen=True)
class RecordStop:
    """A stop of the trolley."""

    t_start_s: float
    t_end_s: float
    label: str
    chainage_m: float


@dataclass(frozen=True)
class RecordNote:
    """A note the crew took (time, internal chainage where the trolley was, text as typed)."""

    t_s: float
    chainage_m: float
    text: str


@dataclass
class FieldRecord:
    """Everything of :data:`FIELD_RECORD`."""

    project: str = ""
    session: str = ""
    header: dict = field(default_factory=dict)
    start_utc: str = ""
    end_utc: str = ""
    fixes: list[RecordFix] = field(default_factory=list)
    setups: list[RecordSetup] = field(default_factory=list)
    overlaps: list[RecordOverlap] = field(default_factory=list)
    stops: list[RecordStop] = field(default_factory=list)
    notes: list[RecordNote] = field(default_factory=list)

    @property
    def rejected(self) -> list[RecordFix]:
        """Fixes the crew or the session rejected or undid (newest decision: not accepted)."""
        return [f for f in self.fixes if not f.accepted]


def stored_fix_covariance(settings, enh_m, sigma_enh_m, setup=None) -> np.ndarray:
    """(3, 3) covariance of a stored fix: its correlations computed again from its station setup
    (``trolley.resection.fix_covariance`` with the project's instrument sigmas and polar model, the
    setup's a priori covariance and variance factor) on the per-axis sigmas it is stored with
    (``trolley.resection.covariance_with_sigmas``); diagonal without a setup.

    Parameters
    ----------
    settings : ``survey.store.ProjectSettings`` (instrument sigmas, polar model).
    enh_m : (3,) the fix, grid E, N, H.
    sigma_enh_m : (3,) its stored 1-sigma.
    setup : the ``survey.store.StationSetupRecord`` it was measured from, or None.

    Returns
    -------
    (3, 3) covariance, m^2.
    """
    from trolley.resection import covariance_with_sigmas, fix_covariance, variance_factor

    sigma = np.asarray(sigma_enh_m, dtype=float).reshape(3)
    if setup is None:
        return np.diag(sigma**2)
    with np.errstate(all="ignore"):
        full = fix_covariance(settings.instrument, setup.covariance, setup.station_enh_m,
                              np.asarray(enh_m, dtype=float), settings.polar_model,
                              variance_factor(setup.sigma0, setup.dof))[0]
    if not np.all(np.isfinite(full)):
        return np.diag(sigma**2)  # a fix on the station's own vertical has no line of sight to correlate by
    return covariance_with_sigmas(full, sigma)


def overlap_checks(fixes: list[RecordFix], tolerance_m: float, covariance=None) -> list[RecordOverlap]:
    """The overlap checks among ``fixes`` (time order): each fix whose reason starts with
    :data:`OVERLAP_PREFIX`, against the last fix before it from another station (preferably an
    accepted one, as the session's ``last_fix`` was). ``covariance(fix)`` gives a fix's (3, 3)
    covariance (:func:`stored_fix_covariance`); without it, the stored sigmas uncorrelated."""
    from trolley.resection import overlap_check

    out = []
    for i, f in enumerate(fixes):
        if not f.reason.startswith(OVERLAP_PREFIX):
            continue
        before = [g for g in fixes[:i] if g.station != f.station]
        old = next((g for g in reversed(before) if g.accepted), before[-1] if before else None)
        if old is None:
            continue
        s_old = np.array([old.sigma_E_m, old.sigma_N_m, old.sigma_H_m])
        s_new = np.array([f.sigma_E_m, f.sigma_N_m, f.sigma_H_m])
        if not (np.all(np.isfinite(s_old)) and np.all(np.isfinite(s_new))):
            covs = (None, None)
        elif covariance is None:
            covs = (np.diag(s_old**2), np.diag(s_new**2))
        else:
            covs = (covariance(old), covariance(f))
        oc = overlap_check(old.point, [old.E_m, old.N_m, old.H_m], [f.E_m, f.N_m, f.H_m], tolerance_m, *covs)
        d, sd = oc.difference_enh_m, oc.sigma_enh_m
        out.append(RecordOverlap(f.t_s, old.point, f.point, old.station, f.station, float(d[0]), float(d[1]),
                                 float(d[2]), tolerance_m, oc.within_tolerance, f.accepted, f.reason,
                                 float(sd[0]), float(sd[1]), float(sd[2]), oc.max_normalized,
                                 oc.sigma_limit if oc.consistent is not None else math.nan, oc.consistent,
                                 oc.mahalanobis))
    return out


def field_record(store, session_name: str) -> FieldRecord:
    """The field record of a stored session (survey.store.ProjectStore)."""
    rec = store.session(session_name)
    sid = rec.session_id
    setups = store.station_setups(sid)
    number = {s.setup_id: k for k, s in enumerate(setups, start=1)}
    fixes = [RecordFix(float(f.t_s), f.point, float(f.e_m), float(f.n_m), float(f.h_m),
                       number.get(f.setup_id, 0), bool(f.accepted), f.reason, float(f.sigma_e_m),
                       float(f.sigma_n_m), float(f.sigma_h_m)) for f in store.fixes(sid)]
    out_setups = []
    for k, s in enumerate(setups, start=1):
        pts = tuple(RecordPointing(o.point_id, o.used, o.across_m, o.along_m, o.height_m, o.residual_hz_rad,
                                   o.residual_zenith_rad, o.residual_distance_m, o.max_standardized, o.flagged,
                                   o.reason) for o in store.setup_observations(s.setup_id))
        e, n, h = (float(x) for x in s.station_enh_m)
        out_setups.append(RecordSetup(k, float(s.t_s), e, n, h, float(s.orientation_rad), float(s.sigma0),
                                      int(s.dof), bool(s.accepted), tuple(s.excluded), pts))
    span = store.session_time_span_utc(sid)
    settings = store.settings()

    def covariance(f: RecordFix) -> np.ndarray:
        # the fix's station number is its setup's place in ``setups`` (0: none)
        return stored_fix_covariance(settings, [f.E_m, f.N_m, f.H_m], [f.sigma_E_m, f.sigma_N_m, f.sigma_H_m],
                                     setups[f.station - 1] if f.station > 0 else None)

    return FieldRecord(
        project=store.info().name, session=session_name, header={**store.header(), **crs_header(store, rec)},
        start_utc=span[0] if span else "", end_utc=span[1] if span else "",
        fixes=fixes, setups=out_setups, overlaps=overlap_checks(fixes, settings.overlap_tolerance_m, covariance),
        stops=[RecordStop(float(p.t_start_s), float(p.t_end_s), p.label, float(p.chainage_m))
               for p in store.stops(sid)],
        notes=[RecordNote(float(n.t_s), float(n.chainage_m), n.text) for n in store.notes(sid)])


def crs_header(store, rec) -> dict[str, str]:
    """The session's coordinate system, height datum and the grid convergence and scale at the
    CPIII centroid (``trolley project set-crs``); {} entries left out when not set."""
    from trolley import units
    from trolley.projection import CrsError

    meta = rec.meta
    crs = getattr(meta, "crs", None) or store.settings().crs
    datum = getattr(meta, "vertical_datum", None) or store.settings().vertical_datum
    out = {}
    if crs:
        out["coordinate_system"] = str(crs)
        try:
            grid = store.site_grid()
        except CrsError as e:          # the header names the problem instead of a figure
            out["grid"] = f"not computed ({e})"
        else:
            if grid is not None:
                out["grid"] = (f"convergence {units.rad_to_deg(grid.convergence_rad):+.6f} deg, "
                               f"scale {grid.combined_scale:.9f} (CPIII centroid)")
    if datum:
        out["height_datum"] = str(datum)
    return out


def _jsonable(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


def record_json(record: FieldRecord) -> str:
    """The JSON text of a field record (NaN written as null)."""
    doc = {"format": FORMAT, **asdict(record)}
    return json.dumps(_jsonable(doc), indent=1, ensure_ascii=False) + "\n"


def write_field_record(folder: Path, record: FieldRecord) -> Path:
    """Write ``folder/field_record.json`` atomically. Returns the path."""
    from survey.tgms_io import write_text_atomic

    path = Path(folder) / FIELD_RECORD
    write_text_atomic(path, record_json(record))
    return path


def read_field_record(path: Path) -> FieldRecord:
    """Read a field_record.json (ExportInputError naming the file and key when unusable)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ExportInputError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ExportInputError(f"{path}: key format must be {FORMAT!r}")

    def num(v):
        return math.nan if v is None else float(v)

    def rows(key, build):
        items = doc.get(key, [])
        if not isinstance(items, list):
            raise ExportInputError(f"{path}: key {key}: expected a list")
        out = []
        for i, d in enumerate(items):
            try:
                out.append(build(d))
            except (TypeError, ValueError, KeyError, AttributeError) as e:
                raise ExportInputError(f"{path}: key {key}[{i}]: {e}") from None
        return out

    def fix(d) -> RecordFix:
        # (older records: no sigmas)
        return RecordFix(num(d["t_s"]), str(d["point"]), num(d["E_m"]), num(d["N_m"]), num(d["H_m"]),
                         int(d["station"]), bool(d["accepted"]), str(d["reason"]),
                         *(num(d.get(k)) for k in ("sigma_E_m", "sigma_N_m", "sigma_H_m")))

    def pointing(d) -> RecordPointing:
        return RecordPointing(str(d["point"]), bool(d["used"]), *(num(d[k]) for k in (
            "across_m", "along_m", "height_m", "hz_rad", "zenith_rad", "distance_m", "max_standardized")),
            bool(d["flagged"]), str(d["reason"]))

    def setup(d) -> RecordSetup:
        return RecordSetup(int(d["station"]), num(d["t_s"]), num(d["E_m"]), num(d["N_m"]), num(d["H_m"]),
                           num(d["orientation_rad"]), num(d["sigma0"]), int(d["dof"]), bool(d["accepted"]),
                           tuple(str(x) for x in d["excluded"]), tuple(pointing(p) for p in d["pointings"]))

    def overlap(d) -> RecordOverlap:
        consistent = d.get("consistent")  # (older records: no sigmas)
        return RecordOverlap(num(d["t_s"]), str(d["old_point"]), str(d["new_point"]), int(d["from_station"]),
                             int(d["to_station"]), num(d["dE_m"]), num(d["dN_m"]), num(d["dH_m"]),
                             num(d["tolerance_m"]), bool(d["within"]), bool(d["accepted"]), str(d["reason"]),
                             *(num(d.get(k)) for k in ("sigma_dE_m", "sigma_dN_m", "sigma_dH_m", "max_d_over_sigma",
                                                       "sigma_limit")),
                             None if consistent is None else bool(consistent), num(d.get("mahalanobis")))

    def stop(d) -> RecordStop:
        return RecordStop(num(d["t_start_s"]), num(d["t_end_s"]), str(d["label"]), num(d["chainage_m"]))

    def note(d) -> RecordNote:
        return RecordNote(num(d["t_s"]), num(d["chainage_m"]), str(d["text"]))

    header = doc.get("header", {})
    if not isinstance(header, dict):
        raise ExportInputError(f"{path}: key header: expected an object")
    return FieldRecord(project=str(doc.get("project", "")), session=str(doc.get("session", "")),
                       header={str(k): str(v) for k, v in header.items()},
                       start_utc=str(doc.get("start_utc", "")), end_utc=str(doc.get("end_utc", "")),
                       fixes=rows("fixes", fix), setups=rows("setups", setup), overlaps=rows("overlaps", overlap),
                       stops=rows("stops", stop), notes=rows("notes", note))   # (older records: no notes)


__all__ = ["FIELD_RECORD", "FORMAT", "FieldRecord", "RecordFix", "RecordSetup", "RecordPointing", "RecordOverlap",
           "RecordStop", "RecordNote", "field_record", "overlap_checks", "stored_fix_covariance", "read_field_record", "record_json", "write_field_record"]
