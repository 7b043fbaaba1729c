"""The project store: one SQLite database per project (``projects/<name>/project.sqlite``).

Embedded, no server: WAL journal (readers never block the writer), foreign keys on, the schema
versioned by ``PRAGMA user_version`` and brought up to date by ordered migration functions when
the file is opened. ``PRAGMA application_id`` marks the file as ours, so the application refuses
to open (and so to migrate) a foreign SQLite file. See ``docs/project_store.md``.

What it holds: project settings; the CPIII control points; the design alignment (LandXML text kept
verbatim plus what was parsed); sessions; station setups with their observations and residuals;
each device's raw bytes and decoded records, append-only (triggers raise on UPDATE or DELETE);
fixes (append-only, with accept/reject decisions appended as events); stops, crew notes, session
events and processed track rows.

Raw data arrive at hundreds of rows per second: ``RecordWriter`` buffers them and a background
thread commits a batch at least every ``flush_interval_s`` (default 0.5 s), so a crash or power
loss loses at most that much (``synchronous=FULL``: a committed batch is on disk).
"""
from __future__ import annotations

import dataclasses
import json
import os
import sqlite3
import threading
import time
import types
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from trolley.resection import InstrumentSigmas, PolarModel, PolarObservations, Resection, ResectionConfig
from trolley.sensors import IMU_PRESETS, ImuFigures, OdometerFigures
from trolley.session import Fixes, RawSession, SessionMeta, TrolleyGeometry

from survey.atomicwrite import file_mode
from survey.names import UnsafeNameError, check_name

#: PRAGMA application_id of a trolley-survey project file ("TRLY").
APPLICATION_ID = 0x54524C59
#: File name of the store inside a project folder.
STORE_FILE = "project.sqlite"


class StoreError(RuntimeError):
    """The project store cannot do what was asked (missing project, conflict, foreign file...)."""


class PointConflict(StoreError):
    """A control point id is already in the project with other coordinates (or twice in one batch)."""

    def __init__(self, point: "ControlPoint", message: str):
        super().__init__(f"{point.source}:{point.line}: {message}")
        self.point = point
        self.detail = message


def utc_now() -> str:
    """Current UTC time, ISO 8601 with seconds."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


# ---------------------------------------------------------------------------------------------
# Row types
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ProjectSettings:
    """Settings of a project; a new session's metadata starts from them.

    Attributes
    ----------
    latitude_rad, height_m : site, for the Earth-rate terms.
    trolley : trolley geometry.
    imu : IMU datasheet figures.
    odometer : odometer figures.
    fix_sigma_m : default 1-sigma of a prism fix per axis.
    static_s : length of the initial static alignment.
    sign_convention : name of the sign convention of deviations, cant, twist ("formats-1" is
        FORMATS.md section 2: lateral + to the right facing increasing chainage, cant + when the
        left rail is higher).
    tolerance_set : name of the tolerance set defects are judged against.
    instrument : a priori total-station sigmas for the resection.
    max_standardized_residual : resection outlier tolerance (data snooping |w|).
    max_point_residual_m : resection metric tolerance per point.
    overlap_tolerance_m : tolerance of the overlap check after a station change.
    polar_model : curvature, refraction and grid scale of the total-station observations
        (``docs/conventions.md``, "Total station"); with a ``crs`` the grid scale is the CRS's
        combined scale at the CPIII centroid instead (:meth:`ProjectStore.site_grid`).
    crs : coordinate reference system of the grid (EPSG code or PROJ string), or None.
    vertical_datum : name of the height datum, or None.
    cpiii_prism_constant_m, trolley_prism_constant_m : additive constant of the CPIII prisms and of
        the trolley prism, m, in Leica's convention (relative to the round prism: round 0.0, 360°
        +0.0231); the session sets the total station to each before measuring that prism and reads
        it back (docs/field_session.md, "Prism constants").
    """

    latitude_rad: float = 0.4886921905584123  # 28 deg
    height_m: float = 50.0
    trolley: TrolleyGeometry = field(default_factory=TrolleyGeometry)
    imu: ImuFigures = field(default_factory=lambda: IMU_PRESETS["rlg"])
    odometer: OdometerFigures = field(default_factory=OdometerFigures)
    fix_sigma_m: float = 0.0006
    static_s: float = 900.0
    sign_convention: str = "formats-1"
    tolerance_set: str = "default"
    instrument: InstrumentSigmas = field(default_factory=InstrumentSigmas)
    max_standardized_residual: float = 3.29
    max_point_residual_m: float = 0.002
    overlap_tolerance_m: float = 0.002
    polar_model: PolarModel = field(default_factory=PolarModel)
    crs: str | None = None
    vertical_datum: str | None = None
    cpiii_prism_constant_m: float = 0.0
    trolley_prism_constant_m: float = 0.0

    def resection_config(self, grid_scale: float | None = None) -> ResectionConfig:
        """Resection weights and tolerances of this project (``grid_scale``: the CRS's combined
        scale at the site, replacing the polar model's)."""
        model = self.polar_model if grid_scale is None else dataclasses.replace(self.polar_model,
                                                                                grid_scale=float(grid_scale))
        return ResectionConfig(sigmas=self.instrument, model=model,
                               max_standardized_residual=self.max_standardized_residual,
                               max_point_residual_m=self.max_point_residual_m)

    def session_meta(self, design_alignment: str | None = None) -> SessionMeta:
        """Metadata of a new session recorded with these settings."""
        return SessionMeta(latitude_rad=self.latitude_rad, height_m=self.height_m, trolley=self.trolley,
                           imu=self.imu, odometer=self.odometer, fix_sigma_m=self.fix_sigma_m,
                           static_s=self.static_s, design_alignment=design_alignment, crs=self.crs,
                           vertical_datum=self.vertical_datum)


@dataclass(frozen=True)
class ProjectInfo:
    """Identity of a project store."""

    name: str
    created_utc: str
    schema_version: int
    path: Path


@dataclass(frozen=True)
class ControlPoint:
    """A CPIII control point in grid coordinates, with where it came from."""

    point_id: str
    e_m: float
    n_m: float
    h_m: float
    source: str = ""
    line: int = 0


@dataclass(frozen=True)
class AlignmentRecord:
    """A design alignment: the LandXML text verbatim plus what was parsed from it.

    ``name`` is the ``Alignment/@name`` chosen in a file that holds several. ``notes`` are what
    the reader reported at import (not stored: reading the text again gives them again).
    """

    file_name: str
    landxml_text: str
    name: str
    element_count: int
    chainage_start_m: float
    chainage_end_m: float
    imported_utc: str = ""
    alignment_id: int | None = None
    notes: tuple[str, ...] = ()

    @property
    def alignment_name(self) -> str | None:
        """The name to pass to the LandXML reader: None when the file holds one alignment."""
        from trolley.landxml import alignment_names

        return self.name if len(alignment_names(self.landxml_text)) > 1 else None

    def design(self, rail_spacing_m: float | None = None):
        """The ``trolley.alignment.Alignment`` this record holds (its text read again)."""
        from trolley.landxml import parse_landxml

        kwargs = {} if rail_spacing_m is None else {"rail_spacing_m": rail_spacing_m}
        return parse_landxml(self.landxml_text, self.alignment_name, **kwargs)


@dataclass(frozen=True)
class SessionRecord:
    """A survey session of the project."""

    session_id: int
    name: str
    created_utc: str
    state: str  # "open", "paused", "ended", "imported"
    source: str  # "live" or "imported"
    meta: SessionMeta
    alignment_id: int | None
    source_toml: str | None


@dataclass(frozen=True)
class RawChunk:
    """Bytes as read from one device, with the host time they arrived."""

    device: str
    t_host_s: float
    payload: bytes


@dataclass(frozen=True)
class ImuRecord:
    """One decoded IMU sample (FRD, as measured)."""

    t_s: float
    wx_rad_s: float
    wy_rad_s: float
    wz_rad_s: float
    fx_m_s2: float
    fy_m_s2: float
    fz_m_s2: float


@dataclass(frozen=True)
class OdometerRecord:
    """One decoded odometer reading (cumulative distance)."""

    t_s: float
    distance_m: float


@dataclass(frozen=True)
class GaugeRecord:
    """One decoded gauge-sensor reading (full gauge)."""

    t_s: float
    gauge_m: float


@dataclass(frozen=True)
class FixRecord:
    """A total-station prism fix (grid E, N, H) and the decision taken on it.

    ``accepted`` and ``reason`` are the latest decision (fixes themselves are never modified;
    decisions are appended).
    """

    t_s: float
    point: str
    e_m: float
    n_m: float
    h_m: float
    sigma_e_m: float
    sigma_n_m: float
    sigma_h_m: float
    setup_id: int | None = None
    accepted: bool = True
    reason: str = ""
    fix_id: int | None = None
    #: covariances E-N, E-H, N-H (m^2) an imported fix came with (fixes.csv's optional columns);
    #: None: a field fix, whose covariances come from its setup (``ProjectStore.fix_covariances``)
    cov_m2: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class StationSetupRecord:
    """A free-station setup: the resection result as stored.

    Attributes
    ----------
    t_s : session time of the setup.
    station_enh_m : (3,) instrument axis point.
    orientation_rad : grid azimuth of the horizontal circle's zero.
    covariance : (4, 4) a priori covariance of E, N, H, orientation.
    sigma0, dof : a posteriori sigma0 and degrees of freedom.
    accepted : the crew accepted it (the total station was given this station).
    excluded : point ids the crew dropped.
    """

    t_s: float
    station_enh_m: np.ndarray
    orientation_rad: float
    covariance: np.ndarray
    sigma0: float
    dof: int
    accepted: bool = True
    excluded: tuple[str, ...] = ()
    setup_id: int | None = None


@dataclass(frozen=True)
class SetupObservation:
    """One pointing of a station setup with its residuals (NaN where not observed or not used)."""

    point_id: str
    hz_rad: float
    zenith_rad: float
    slope_distance_m: float
    used: bool = True
    residual_hz_rad: float = float("nan")
    residual_zenith_rad: float = float("nan")
    residual_distance_m: float = float("nan")
    across_m: float = float("nan")
    along_m: float = float("nan")
    height_m: float = float("nan")
    max_standardized: float = float("nan")
    flagged: bool = False
    reason: str = ""


def setup_rows(result: Resection, point_ids: Sequence[str], observations: PolarObservations, t_s: float,
               accepted: bool = True) -> tuple[StationSetupRecord, list[SetupObservation]]:
    """Rows to store for a resection: the setup and every pointing (excluded ones with ``used=False``).

    Parameters
    ----------
    result : the resection.
    point_ids, observations : all pointings measured, including those the crew excluded, in the
        order they were given to ``resect``.
    t_s : session time of the setup.
    accepted : whether the crew accepted it.
    """
    setup = StationSetupRecord(t_s=float(t_s), station_enh_m=np.asarray(result.station_enh_m, dtype=float).copy(),
                               orientation_rad=result.orientation_rad, covariance=np.asarray(result.covariance).copy(),
                               sigma0=result.sigma0, dof=result.dof, accepted=accepted, excluded=result.excluded)
    residuals = iter(result.residuals)
    rows = []
    for i, pid in enumerate(point_ids):
        hz, z, sd = (float(observations.hz_rad[i]), float(observations.zenith_rad[i]),
                     float(observations.slope_distance_m[i]))
        if str(pid) in result.excluded:
            rows.append(SetupObservation(str(pid), hz, z, sd, used=False, reason="excluded by the crew"))
            continue
        r = next(residuals)
        rows.append(SetupObservation(str(pid), hz, z, sd, True, r.hz_rad, r.zenith_rad, r.distance_m, r.across_m,
                                     r.along_m, r.height_m, r.max_standardized, r.flagged, r.reason))
    return setup, rows


@dataclass(frozen=True)
class StopRecord:
    """A stop of the trolley (it stood still between these times)."""

    t_start_s: float
    t_end_s: float
    label: str = ""
    chainage_m: float = float("nan")
    stop_id: int | None = None


@dataclass(frozen=True)
class NoteRecord:
    """A crew note at a time and chainage."""

    t_s: float
    text: str
    chainage_m: float = float("nan")
    created_utc: str = ""
    note_id: int | None = None


@dataclass(frozen=True)
class SessionEvent:
    """Something that happened in a session: pause, resume, turn, station_change, device_fault, end."""

    t_s: float
    kind: str
    detail: str = ""
    event_id: int | None = None


@dataclass
class TrackResult:
    """Processed track rows (FORMATS.md section 2 columns in SI), one array per column.

    NaN where a value is empty (no design, not measured).
    """

    chainage_m: np.ndarray
    enh_m: np.ndarray  # (n, 3)
    sigma_enh_m: np.ndarray  # (n, 3)
    lateral_dev_m: np.ndarray
    vertical_dev_m: np.ndarray
    gauge_m: np.ndarray
    cant_m: np.ndarray
    twist_m: np.ndarray

    def __len__(self) -> int:
        return int(self.chainage_m.shape[0])


@dataclass(frozen=True)
class ProcessingRun:
    """One processing of (part of) a session whose track rows are stored."""

    run_id: int
    session_id: int
    kind: str  # "interval", "final", or "interval_undone" (its closing fix undone by the crew)
    t_start_s: float
    t_end_s: float
    created_utc: str
    row_count: int


@dataclass(frozen=True)
class RecordCount:
    """Rows stored for a session in one raw or decoded table."""

    table: str
    device: str
    rows: int


# ---------------------------------------------------------------------------------------------
# Dataclass <-> JSON (settings and session metadata are stored as JSON of their dataclasses)
# ---------------------------------------------------------------------------------------------

def _to_jsonable(obj):
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (tuple, list)):
        return [_to_jsonable(x) for x in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _from_jsonable(tp, data):
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        if data is None:
            return None
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _from_jsonable(args[0], data)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp)
        kwargs = {f.name: _from_jsonable(hints[f.name], data[f.name])
                  for f in dataclasses.fields(tp) if f.name in data}
        return tp(**kwargs)
    if tp is np.ndarray:
        return np.asarray(data, dtype=float)
    if origin is tuple:
        return tuple(data)
    if tp is float:
        return float(data)
    return data


def settings_to_json(settings: ProjectSettings) -> str:
    """JSON text of project settings."""
    return json.dumps(_to_jsonable(settings), sort_keys=True)


def settings_from_json(text: str) -> ProjectSettings:
    """Project settings from their JSON text (missing keys take their defaults)."""
    return _from_jsonable(ProjectSettings, json.loads(text))


def meta_to_json(meta: SessionMeta) -> str:
    """JSON text of session metadata."""
    return json.dumps(_to_jsonable(meta), sort_keys=True)


def meta_from_json(text: str) -> SessionMeta:
    """Session metadata from its JSON text."""
    return _from_jsonable(SessionMeta, json.loads(text))


# ---------------------------------------------------------------------------------------------
# Schema and migrations
# ---------------------------------------------------------------------------------------------

def _append_only(conn: sqlite3.Connection, table: str) -> None:
    for op in ("UPDATE", "DELETE"):
        conn.execute(f"CREATE TRIGGER {table}_no_{op.lower()} BEFORE {op} ON {table} "
                     f"BEGIN SELECT RAISE(ABORT, '{table} is append-only'); END")


def _migration_1(conn: sqlite3.Connection) -> None:
    """Initial schema: project, settings, CPIII, alignment, sessions, setups, raw and decoded data, fixes."""
    stmts = [
        "CREATE TABLE project (id INTEGER PRIMARY KEY CHECK (id = 1), name TEXT NOT NULL, created_utc TEXT NOT NULL)",
        "CREATE TABLE setting (key TEXT PRIMARY KEY, value_json TEXT NOT NULL)",
        """CREATE TABLE cpiii_point (point_id TEXT PRIMARY KEY, e_m REAL NOT NULL, n_m REAL NOT NULL,
               h_m REAL NOT NULL, source TEXT NOT NULL, line INTEGER NOT NULL, imported_utc TEXT NOT NULL)""",
        """CREATE TABLE alignment (id INTEGER PRIMARY KEY, file_name TEXT NOT NULL, name TEXT NOT NULL,
               landxml_text TEXT NOT NULL, element_count INTEGER NOT NULL, chainage_start_m REAL NOT NULL,
               chainage_end_m REAL NOT NULL, imported_utc TEXT NOT NULL)""",
        """CREATE TABLE session (id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE, created_utc TEXT NOT NULL,
               state TEXT NOT NULL, source TEXT NOT NULL, meta_json TEXT NOT NULL, source_toml TEXT,
               alignment_id INTEGER REFERENCES alignment(id))""",
        """CREATE TABLE station_setup (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, e_m REAL NOT NULL, n_m REAL NOT NULL, h_m REAL NOT NULL,
               orientation_rad REAL NOT NULL, covariance_json TEXT NOT NULL, sigma0 REAL, dof INTEGER NOT NULL,
               accepted INTEGER NOT NULL, excluded_json TEXT NOT NULL, created_utc TEXT NOT NULL)""",
        """CREATE TABLE setup_observation (id INTEGER PRIMARY KEY,
               setup_id INTEGER NOT NULL REFERENCES station_setup(id), point_id TEXT NOT NULL,
               hz_rad REAL, zenith_rad REAL, slope_distance_m REAL, used INTEGER NOT NULL,
               residual_hz_rad REAL, residual_zenith_rad REAL, residual_distance_m REAL,
               across_m REAL, along_m REAL, height_m REAL, max_standardized REAL,
               flagged INTEGER NOT NULL, reason TEXT NOT NULL)""",
        """CREATE TABLE raw_chunk (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               device TEXT NOT NULL, t_host_s REAL NOT NULL, payload BLOB NOT NULL)""",
        """CREATE TABLE imu_sample (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, wx_rad_s REAL NOT NULL, wy_rad_s REAL NOT NULL, wz_rad_s REAL NOT NULL,
               fx_m_s2 REAL NOT NULL, fy_m_s2 REAL NOT NULL, fz_m_s2 REAL NOT NULL)""",
        """CREATE TABLE odometer_sample (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, distance_m REAL NOT NULL)""",
        """CREATE TABLE gauge_sample (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, gauge_m REAL NOT NULL)""",
        """CREATE TABLE fix (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, point TEXT NOT NULL, e_m REAL NOT NULL, n_m REAL NOT NULL, h_m REAL NOT NULL,
               sigma_e_m REAL NOT NULL, sigma_n_m REAL NOT NULL, sigma_h_m REAL NOT NULL,
               setup_id INTEGER REFERENCES station_setup(id))""",
        """CREATE TABLE fix_decision (id INTEGER PRIMARY KEY, fix_id INTEGER NOT NULL REFERENCES fix(id),
               accepted INTEGER NOT NULL, reason TEXT NOT NULL, created_utc TEXT NOT NULL)""",
        "CREATE INDEX raw_chunk_session ON raw_chunk(session_id, device)",
        "CREATE INDEX imu_sample_session ON imu_sample(session_id, t_s)",
        "CREATE INDEX odometer_sample_session ON odometer_sample(session_id, t_s)",
        "CREATE INDEX gauge_sample_session ON gauge_sample(session_id, t_s)",
        "CREATE INDEX fix_session ON fix(session_id, t_s)",
        "CREATE INDEX fix_decision_fix ON fix_decision(fix_id)",
    ]
    for s in stmts:
        conn.execute(s)
    for t in ("raw_chunk", "imu_sample", "odometer_sample", "gauge_sample", "fix", "fix_decision",
              "setup_observation"):
        _append_only(conn, t)


def _migration_2(conn: sqlite3.Connection) -> None:
    """Field-session tables: stops, crew notes, session events, processed track rows."""
    stmts = [
        """CREATE TABLE stop (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_start_s REAL NOT NULL, t_end_s REAL NOT NULL, label TEXT NOT NULL, chainage_m REAL)""",
        """CREATE TABLE note (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, chainage_m REAL, text TEXT NOT NULL, created_utc TEXT NOT NULL)""",
        """CREATE TABLE session_event (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               t_s REAL NOT NULL, kind TEXT NOT NULL, detail TEXT NOT NULL, created_utc TEXT NOT NULL)""",
        """CREATE TABLE processing_run (id INTEGER PRIMARY KEY, session_id INTEGER NOT NULL REFERENCES session(id),
               kind TEXT NOT NULL, t_start_s REAL NOT NULL, t_end_s REAL NOT NULL, created_utc TEXT NOT NULL)""",
        """CREATE TABLE track_row (id INTEGER PRIMARY KEY, run_id INTEGER NOT NULL REFERENCES processing_run(id),
               chainage_m REAL NOT NULL, e_m REAL NOT NULL, n_m REAL NOT NULL, h_m REAL NOT NULL,
               sigma_e_m REAL, sigma_n_m REAL, sigma_h_m REAL, lateral_dev_m REAL, vertical_dev_m REAL,
               gauge_m REAL, cant_m REAL, twist_m REAL)""",
        "CREATE INDEX note_session ON note(session_id, t_s)",
        "CREATE INDEX session_event_session ON session_event(session_id, t_s)",
        "CREATE INDEX track_row_run ON track_row(run_id, chainage_m)",
    ]
    for s in stmts:
        conn.execute(s)
    _append_only(conn, "session_event")


def _migration_3(conn: sqlite3.Connection) -> None:
    """The covariances between an imported fix's axes (fixes.csv ``cov_EN_m2, cov_EH_m2, cov_NH_m2``):
    NULL for a field fix, whose covariances are computed from its station setup."""
    for col in ("cov_en_m2", "cov_eh_m2", "cov_nh_m2"):
        conn.execute(f"ALTER TABLE fix ADD COLUMN {col} REAL")


#: Ordered migrations; migration i (1-based) brings user_version from i-1 to i. Append only.
MIGRATIONS: list[Callable[[sqlite3.Connection], None]] = [_migration_1, _migration_2, _migration_3]
#: Schema version this code writes.
SCHEMA_VERSION = len(MIGRATIONS)


def schema_version(conn: sqlite3.Connection) -> int:
    """PRAGMA user_version of an open database."""
    return int(conn.execute("PRAGMA user_version").fetchone()[0])


def migrate(conn: sqlite3.Connection, target: int = SCHEMA_VERSION) -> int:
    """Apply the migrations from the database's version up to ``target``, each in its own transaction.

    Returns
    -------
    The version reached.
    """
    current = schema_version(conn)
    if current > SCHEMA_VERSION:
        raise StoreError(f"the project file has schema version {current}, newer than this software "
                         f"({SCHEMA_VERSION}): update trolley-survey")
    for version in range(current + 1, target + 1):
        conn.execute("BEGIN IMMEDIATE")
        try:
            MIGRATIONS[version - 1](conn)
            conn.execute(f"PRAGMA user_version = {version}")
            conn.execute("COMMIT")
        except BaseException:
            _rollback(conn)
            raise
    return schema_version(conn)


def _rollback(conn: sqlite3.Connection) -> None:
    """Roll back the open transaction, if SQLite has not already done so itself (it does after a
    full disk or an I/O error: a second ROLLBACK would hide that error behind its own)."""
    if conn.in_transaction:
        conn.execute("ROLLBACK")


def connect(path: Path, *, check_same_thread: bool = True) -> sqlite3.Connection:
    """A connection with the store's pragmas (WAL, foreign keys, full sync, busy timeout), autocommit mode."""
    conn = sqlite3.connect(str(path), isolation_level=None, check_same_thread=check_same_thread, timeout=10.0)
    conn.execute("PRAGMA foreign_keys = ON")
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA synchronous = FULL")
    return conn


def _check_name(kind: str, name: str) -> None:
    """A project or session name that is a plain folder name (survey.names.check_name)."""
    try:
        check_name(kind, name)
    except UnsafeNameError as exc:
        raise StoreError(str(exc)) from None


def _check_ours(path: Path) -> None:
    """Refuse a file that is not a trolley-survey store *before* anything writes to it.

    Read through a read-only connection: no WAL switch, no migration, not a byte changed in a
    foreign SQLite file or a corrupt one.
    """
    if path.is_file() and not (os.access(path, os.W_OK) and os.access(path.parent, os.W_OK)):
        # (SQLite then says only "unable to open database file": its journal cannot be made)
        raise StoreError(f"{path}: the project store is read-only (a write-protected disk, card or folder); "
                         "copy the project folder to a writable place and use the copy")
    try:
        ro = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise StoreError(f"{path}: cannot open the project store ({exc})") from None
    try:
        app_id = int(ro.execute("PRAGMA application_id").fetchone()[0])
    except sqlite3.DatabaseError as exc:
        raise StoreError(f"{path}: not a trolley-survey project store (not a usable SQLite file: {exc})") from None
    finally:
        ro.close()
    if app_id != APPLICATION_ID:
        raise StoreError(f"{path}: not a trolley-survey project store (SQLite application_id {app_id:#x}, "
                         f"expected {APPLICATION_ID:#x}); left unchanged")


def project_path(root: Path | str, name: str) -> Path:
    """Path of a project's store file: ``<root>/<name>/project.sqlite``."""
    return Path(root) / name / STORE_FILE


def _float(x) -> float:
    return float("nan") if x is None else float(x)


def _nullable(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


# ---------------------------------------------------------------------------------------------
# The store
# ---------------------------------------------------------------------------------------------

class ProjectStore:
    """One project's SQLite store. Use ``ProjectStore.create`` or ``ProjectStore.open``; close it
    (or use it as a context manager). Each write method is one transaction."""

    def __init__(self, path: Path, conn: sqlite3.Connection):
        self.path = Path(path)
        self._conn = conn

    # -- opening ---------------------------------------------------------------------------------
    @classmethod
    def create(cls, root: Path | str, name: str, settings: ProjectSettings | None = None) -> "ProjectStore":
        """Create ``<root>/<name>/project.sqlite``; error if it exists.

        The store is built complete in a hidden temporary file beside it and linked into place
        only then, so a full disk or a crash leaves no stub ``project.sqlite`` (and no project
        folder that was not there before).
        """
        _check_name("project name", name)
        path = project_path(root, name)
        if path.exists():
            raise StoreError(f"project {name!r} already exists: {path}")
        made = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
        try:
            conn = sqlite3.connect(str(tmp), isolation_level=None)
            try:
                conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
                conn.execute("PRAGMA synchronous = FULL")
                migrate(conn)
                conn.execute("BEGIN IMMEDIATE")
                conn.execute("INSERT INTO project (id, name, created_utc) VALUES (1, ?, ?)", (name, utc_now()))
                conn.execute("INSERT INTO setting (key, value_json) VALUES ('project', ?)",
                             (settings_to_json(settings or ProjectSettings()),))
                conn.execute("COMMIT")
            finally:
                conn.close()
            os.chmod(tmp, file_mode())
            os.link(tmp, path)  # fails if someone created the project meanwhile: never replaced
        except BaseException:
            for p in (tmp, tmp.with_name(tmp.name + "-journal")):
                p.unlink(missing_ok=True)
            for p in made:
                try:
                    p.rmdir()
                except OSError:
                    pass
            raise
        finally:
            tmp.unlink(missing_ok=True)
        return cls.open(path)

    @classmethod
    def open(cls, path: Path | str) -> "ProjectStore":
        """Open a store (a ``project.sqlite`` file or its project folder) and migrate it to the current schema."""
        path = Path(path)
        if path.is_dir():
            path = path / STORE_FILE
        if not path.is_file():
            raise StoreError(f"no project store at {path}")
        _check_ours(path)
        try:
            conn = connect(path)
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{path}: cannot open the project store ({exc})") from None
        try:
            migrate(conn)
        except sqlite3.DatabaseError as exc:
            conn.close()
            raise StoreError(f"{path}: the project store is damaged or read-only ({exc})") from None
        except BaseException:
            conn.close()
            raise
        return cls(path, conn)

    @classmethod
    def open_project(cls, root: Path | str, name: str) -> "ProjectStore":
        """Open the project ``name`` under ``root``."""
        _check_name("project name", name)
        if Path(root).exists() and not Path(root).is_dir():
            raise StoreError(f"--root {root}: is a file, not a folder of projects")
        path = project_path(root, name)
        if path.is_dir():
            raise StoreError(f"{path}: is a folder, not a project store")
        if not path.is_file():
            raise StoreError(f"no project {name!r} under {Path(root)} (create it with `trolley project new {name}`)")
        return cls.open(path)

    def close(self) -> None:
        """Close the connection."""
        self._conn.close()

    def __enter__(self) -> "ProjectStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    class _Tx:
        def __init__(self, conn: sqlite3.Connection):
            self.conn = conn

        def __enter__(self):
            self.conn.execute("BEGIN IMMEDIATE")
            return self.conn

        def __exit__(self, exc_type, exc, tb):
            if exc_type:
                _rollback(self.conn)
            else:
                self.conn.execute("COMMIT")
            return False

    def _transaction(self) -> "ProjectStore._Tx":
        return ProjectStore._Tx(self._conn)

    @property
    def connection(self) -> sqlite3.Connection:
        """The underlying connection (for reading; writes go through the methods)."""
        return self._conn

    # -- project ---------------------------------------------------------------------------------
    def info(self) -> ProjectInfo:
        """Name, creation time and schema version."""
        name, created = self._conn.execute("SELECT name, created_utc FROM project WHERE id = 1").fetchone()
        return ProjectInfo(name=name, created_utc=created, schema_version=schema_version(self._conn), path=self.path)

    def settings(self) -> ProjectSettings:
        """The project settings."""
        row = self._conn.execute("SELECT value_json FROM setting WHERE key = 'project'").fetchone()
        return settings_from_json(row[0]) if row else ProjectSettings()

    def set_settings(self, settings: ProjectSettings) -> None:
        """Replace the project settings."""
        with self._transaction() as c:
            c.execute("INSERT OR REPLACE INTO setting (key, value_json) VALUES ('project', ?)",
                      (settings_to_json(settings),))

    # -- survey header (`trolley project set`) ---------------------------------------------------
    def header(self) -> dict[str, str]:
        """The survey header fields the crew gave (survey.surveyheader.HEADER_FIELDS keys)."""
        row = self._conn.execute("SELECT value_json FROM setting WHERE key = 'header'").fetchone()
        return dict(json.loads(row[0])) if row else {}

    def set_header(self, key: str, value: str) -> str:
        """Set (or with an empty value clear) one header field after checking it
        (:func:`survey.surveyheader.check_header_value`; ValueError when bad). Returns the value stored."""
        from survey.surveyheader import check_header_value

        text = check_header_value(key, value)
        with self._transaction() as c:
            row = c.execute("SELECT value_json FROM setting WHERE key = 'header'").fetchone()
            doc = dict(json.loads(row[0])) if row else {}
            if text:
                doc[key] = text
            else:
                doc.pop(key, None)
            c.execute("INSERT OR REPLACE INTO setting (key, value_json) VALUES ('header', ?)", (json.dumps(doc),))
        return text

    # -- CPIII -----------------------------------------------------------------------------------
    def add_cpiii_points(self, points: Sequence[ControlPoint]) -> int:
        """Add control points in one transaction.

        A point id already in the project with the same coordinates (to 0.1 mm) is skipped; with
        different coordinates it is an error naming the point's source and line, and nothing is added.

        Returns
        -------
        Number of points added.
        """
        seen: dict[str, ControlPoint] = {}
        for p in points:
            if p.point_id in seen:
                q = seen[p.point_id]
                raise PointConflict(p, f"duplicate point id {p.point_id!r} (first on line {q.line})")
            seen[p.point_id] = p
        added = 0
        now = utc_now()
        with self._transaction() as c:
            for p in points:
                old = c.execute("SELECT e_m, n_m, h_m, source, line FROM cpiii_point WHERE point_id = ?",
                                (p.point_id,)).fetchone()
                if old is not None:
                    if max(abs(old[0] - p.e_m), abs(old[1] - p.n_m), abs(old[2] - p.h_m)) > 1e-4:
                        raise PointConflict(p, f"point {p.point_id!r} is already in the project with other "
                                               f"coordinates (from {old[3]}:{old[4]})")
                    continue
                c.execute("INSERT INTO cpiii_point (point_id, e_m, n_m, h_m, source, line, imported_utc) "
                          "VALUES (?, ?, ?, ?, ?, ?, ?)", (p.point_id, p.e_m, p.n_m, p.h_m, p.source, p.line, now))
                added += 1
        return added

    def cpiii_points(self) -> list[ControlPoint]:
        """All control points, by id."""
        rows = self._conn.execute("SELECT point_id, e_m, n_m, h_m, source, line FROM cpiii_point ORDER BY point_id")
        return [ControlPoint(*r) for r in rows]

    def session_meta(self, design_alignment: str | None = None) -> SessionMeta:
        """Metadata of a new session: the settings', with the site latitude the CRS gives at the
        CPIII centroid when the project has a CRS (:meth:`site_grid`)."""
        meta = self.settings().session_meta(design_alignment)
        grid = self.site_grid()
        if grid is not None:
            meta = dataclasses.replace(meta, latitude_rad=grid.latitude_rad)
        return meta

    def site_grid(self):
        """The project CRS's factors at the CPIII centroid (``trolley.projection.GridFactors``), or
        None without a CRS or without CPIII points."""
        crs = self.settings().crs
        pts = self.cpiii_points()
        if not crs or not pts:
            return None
        from trolley.projection import site_factors
        return site_factors(crs, np.array([[p.e_m, p.n_m, p.h_m] for p in pts]))

    def cpiii_point(self, point_id: str) -> ControlPoint | None:
        """One control point, or None."""
        r = self._conn.execute("SELECT point_id, e_m, n_m, h_m, source, line FROM cpiii_point WHERE point_id = ?",
                               (point_id,)).fetchone()
        return ControlPoint(*r) if r else None

    # -- alignment -------------------------------------------------------------------------------
    def add_alignment(self, rec: AlignmentRecord) -> int:
        """Store a design alignment; the newest is the project's current one. Returns its id."""
        with self._transaction() as c:
            return _insert_alignment(c, rec)

    def alignment(self, alignment_id: int | None = None) -> AlignmentRecord | None:
        """An alignment by id, or the current (newest) one; None if there is none."""
        sql = ("SELECT file_name, landxml_text, name, element_count, chainage_start_m, chainage_end_m, "
               "imported_utc, id FROM alignment ")
        r = (self._conn.execute(sql + "WHERE id = ?", (alignment_id,)).fetchone() if alignment_id is not None
             else self._conn.execute(sql + "ORDER BY id DESC LIMIT 1").fetchone())
        return AlignmentRecord(*r) if r else None

    # -- sessions --------------------------------------------------------------------------------
    def create_session(self, name: str, meta: SessionMeta | None = None, *, source: str = "live",
                       source_toml: str | None = None, alignment_id: int | None = None) -> SessionRecord:
        """Create a session (metadata from the project settings when not given)."""
        _check_name("session name", name)
        if meta is None:
            meta = self.session_meta()
        state = "open" if source == "live" else "imported"
        with self._transaction() as c:
            if c.execute("SELECT 1 FROM session WHERE name = ?", (name,)).fetchone():
                raise StoreError(f"session {name!r} already exists in project {self.info().name!r}")
            c.execute("INSERT INTO session (name, created_utc, state, source, meta_json, source_toml, alignment_id) "
                      "VALUES (?, ?, ?, ?, ?, ?, ?)",
                      (name, utc_now(), state, source, meta_to_json(meta), source_toml, alignment_id))
        return self.session(name)

    def _session_from_row(self, r) -> SessionRecord:
        return SessionRecord(session_id=r[0], name=r[1], created_utc=r[2], state=r[3], source=r[4],
                             meta=meta_from_json(r[5]), source_toml=r[6], alignment_id=r[7])

    _SESSION_SQL = "SELECT id, name, created_utc, state, source, meta_json, source_toml, alignment_id FROM session "

    def session(self, name: str) -> SessionRecord:
        """A session by name (StoreError if there is none)."""
        r = self._conn.execute(self._SESSION_SQL + "WHERE name = ?", (name,)).fetchone()
        if r is None:
            raise StoreError(f"no session {name!r} in project {self.info().name!r}")
        return self._session_from_row(r)

    def sessions(self) -> list[SessionRecord]:
        """All sessions, oldest first."""
        return [self._session_from_row(r) for r in self._conn.execute(self._SESSION_SQL + "ORDER BY id")]

    def set_session_state(self, session_id: int, state: str) -> None:
        """Set a session's state ("open", "paused", "ended", "imported")."""
        with self._transaction() as c:
            c.execute("UPDATE session SET state = ? WHERE id = ?", (state, session_id))

    # -- station setups --------------------------------------------------------------------------
    def add_station_setup(self, session_id: int, setup: StationSetupRecord,
                          observations: Sequence[SetupObservation]) -> int:
        """Store a setup and its pointings in one transaction. Returns the setup id."""
        with self._transaction() as c:
            cur = c.execute(
                "INSERT INTO station_setup (session_id, t_s, e_m, n_m, h_m, orientation_rad, covariance_json, "
                "sigma0, dof, accepted, excluded_json, created_utc) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (session_id, setup.t_s, *map(float, setup.station_enh_m), setup.orientation_rad,
                 json.dumps(np.asarray(setup.covariance, dtype=float).tolist()), _nullable(setup.sigma0),
                 setup.dof, int(setup.accepted), json.dumps(list(setup.excluded)), utc_now()))
            setup_id = int(cur.lastrowid)
            c.executemany(
                "INSERT INTO setup_observation (setup_id, point_id, hz_rad, zenith_rad, slope_distance_m, used, "
                "residual_hz_rad, residual_zenith_rad, residual_distance_m, across_m, along_m, height_m, "
                "max_standardized, flagged, reason) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                [(setup_id, o.point_id, _nullable(o.hz_rad), _nullable(o.zenith_rad), _nullable(o.slope_distance_m),
                  int(o.used), _nullable(o.residual_hz_rad), _nullable(o.residual_zenith_rad),
                  _nullable(o.residual_distance_m), _nullable(o.across_m), _nullable(o.along_m),
                  _nullable(o.height_m), _nullable(o.max_standardized), int(o.flagged), o.reason)
                 for o in observations])
        return setup_id

    def fix_covariances(self, session_id: int, fixes) -> np.ndarray:
        """(n, 3) covariances E-N, E-H, N-H of stored fixes (``Fixes.cov_m2``), m^2: those an imported
        fix came with, else each fix's correlations computed again from its station setup, on the
        sigmas it is stored with (:func:`survey.fieldrecord.stored_fix_covariance`; 0 for a fix
        without either). Without them
        the engine took a polar fix's E and N as independent: its lateral sigma was 2.5 x the error
        on the demo, whose instrument looks along the track."""
        from survey.fieldrecord import stored_fix_covariance
        from trolley.session import off_diagonal

        if not fixes:
            return np.zeros((0, 3))
        settings = self.settings()
        setups = {s.setup_id: s for s in self.station_setups(session_id)}
        # one per stop: a few dozen per session
        cov = [stored_fix_covariance(settings, (f.e_m, f.n_m, f.h_m), (f.sigma_e_m, f.sigma_n_m, f.sigma_h_m),
                                     setups.get(f.setup_id)) for f in fixes]
        out = off_diagonal(np.array(cov))
        for i, f in enumerate(fixes):
            if f.cov_m2 is not None:
                out[i] = f.cov_m2
        return out

    def station_setups(self, session_id: int) -> list[StationSetupRecord]:
        """A session's setups, oldest first."""
        rows = self._conn.execute(
            "SELECT t_s, e_m, n_m, h_m, orientation_rad, covariance_json, sigma0, dof, accepted, excluded_json, id "
            "FROM station_setup WHERE session_id = ? ORDER BY id", (session_id,))
        return [StationSetupRecord(t_s=r[0], station_enh_m=np.array(r[1:4]), orientation_rad=r[4],
                                   covariance=np.array(json.loads(r[5])), sigma0=_float(r[6]), dof=r[7],
                                   accepted=bool(r[8]), excluded=tuple(json.loads(r[9])), setup_id=r[10])
                for r in rows]

    def setup_observations(self, setup_id: int) -> list[SetupObservation]:
        """A setup's pointings with their residuals."""
        rows = self._conn.execute(
            "SELECT point_id, hz_rad, zenith_rad, slope_distance_m, used, residual_hz_rad, residual_zenith_rad, "
            "residual_distance_m, across_m, along_m, height_m, max_standardized, flagged, reason "
            "FROM setup_observation WHERE setup_id = ? ORDER BY id", (setup_id,))
        return [SetupObservation(r[0], _float(r[1]), _float(r[2]), _float(r[3]), bool(r[4]), _float(r[5]),
                                 _float(r[6]), _float(r[7]), _float(r[8]), _float(r[9]), _float(r[10]),
                                 _float(r[11]), bool(r[12]), r[13]) for r in rows]

    # -- fixes -----------------------------------------------------------------------------------
    def add_fix(self, session_id: int, fix: FixRecord) -> int:
        """Store a fix and its decision (one transaction). Returns the fix id."""
        with self._transaction() as c:
            fix_id = _insert_fix(c, session_id, fix)
        return fix_id

    def decide_fix(self, fix_id: int, accepted: bool, reason: str,
                   event: tuple[int, SessionEvent] | None = None, withdraw_interval: int | None = None) -> None:
        """Append a decision on a fix (accept, reject, undo); the newest decision counts. ``event``
        (session id, event) is stored in the same transaction: a resumed script then knows the
        step was done (a crew's undo done twice would undo the fix before it).

        ``withdraw_interval``: the run id of the live interval summary the undone fix had closed
        (needs ``event``). In the same transaction its processing run becomes kind
        ``interval_undone`` and an ``interval_undone`` event (JSON: run id, fix id) is stored at the
        event's time: a kill between the undo and the withdrawal would leave the summary of an
        interval that no accepted fix closes (:meth:`interval_summaries` leaves it out)."""
        with self._transaction() as c:
            c.execute("INSERT INTO fix_decision (fix_id, accepted, reason, created_utc) VALUES (?, ?, ?, ?)",
                      (fix_id, int(accepted), reason, utc_now()))
            if event is not None:
                self._insert_event(c, *event)
            if withdraw_interval is not None:
                if event is None:
                    raise ValueError("withdrawing an interval summary needs the undo event")
                sid, ev = event
                c.execute("UPDATE processing_run SET kind = 'interval_undone' WHERE id = ? AND kind = 'interval'",
                          (withdraw_interval,))
                self._insert_event(c, sid, SessionEvent(ev.t_s, "interval_undone", json.dumps(
                    {"run_id": withdraw_interval, "fix_id": fix_id})))

    def fixes(self, session_id: int, accepted_only: bool = False) -> list[FixRecord]:
        """A session's fixes in time order, each with its newest decision."""
        rows = self._conn.execute(
            "SELECT f.t_s, f.point, f.e_m, f.n_m, f.h_m, f.sigma_e_m, f.sigma_n_m, f.sigma_h_m, f.setup_id, "
            "d.accepted, d.reason, f.id, f.cov_en_m2, f.cov_eh_m2, f.cov_nh_m2 FROM fix f JOIN fix_decision d ON d.id = "
            "(SELECT MAX(id) FROM fix_decision WHERE fix_id = f.id) WHERE f.session_id = ? ORDER BY f.t_s, f.id",
            (session_id,))
        out = [FixRecord(*r[:9], accepted=bool(r[9]), reason=r[10], fix_id=r[11],
                         cov_m2=None if r[12] is None else tuple(r[12:15])) for r in rows]
        return [f for f in out if f.accepted] if accepted_only else out

    # -- stops, notes, events --------------------------------------------------------------------
    @staticmethod
    def _insert_stop(c, session_id: int, stop: StopRecord) -> int:
        cur = c.execute("INSERT INTO stop (session_id, t_start_s, t_end_s, label, chainage_m) VALUES (?, ?, ?, ?, ?)",
                        (session_id, stop.t_start_s, stop.t_end_s, stop.label, _nullable(stop.chainage_m)))
        return int(cur.lastrowid)

    @staticmethod
    def _insert_event(c, session_id: int, event: SessionEvent) -> int:
        cur = c.execute("INSERT INTO session_event (session_id, t_s, kind, detail, created_utc) VALUES (?, ?, ?, ?, ?)",
                        (session_id, event.t_s, event.kind, event.detail, utc_now()))
        return int(cur.lastrowid)

    def add_stop(self, session_id: int, stop: StopRecord) -> int:
        """Store a stop. Returns its id."""
        with self._transaction() as c:
            return self._insert_stop(c, session_id, stop)

    def end_session(self, session_id: int, event: SessionEvent, final_stop: StopRecord | None = None) -> None:
        """Store the stop a session ends at (when the trolley stands there), its end event and the
        state "ended" in one transaction: a kill between them cannot store that stop twice (a
        resumed session would be standing there again)."""
        with self._transaction() as c:
            if final_stop is not None:
                self._insert_stop(c, session_id, final_stop)
            self._insert_event(c, session_id, event)
            c.execute("UPDATE session SET state = ? WHERE id = ?", ("ended", session_id))

    def stops(self, session_id: int) -> list[StopRecord]:
        """A session's stops in time order."""
        rows = self._conn.execute("SELECT t_start_s, t_end_s, label, chainage_m, id FROM stop WHERE session_id = ? "
                                  "ORDER BY t_start_s, id", (session_id,))
        return [StopRecord(r[0], r[1], r[2], _float(r[3]), r[4]) for r in rows]

    def add_note(self, session_id: int, note: NoteRecord) -> int:
        """Store a crew note. Returns its id."""
        with self._transaction() as c:
            cur = c.execute("INSERT INTO note (session_id, t_s, chainage_m, text, created_utc) VALUES (?, ?, ?, ?, ?)",
                            (session_id, note.t_s, _nullable(note.chainage_m), note.text, note.created_utc or utc_now()))
            return int(cur.lastrowid)

    def notes(self, session_id: int) -> list[NoteRecord]:
        """A session's notes in time order."""
        rows = self._conn.execute("SELECT t_s, text, chainage_m, created_utc, id FROM note WHERE session_id = ? "
                                  "ORDER BY t_s, id", (session_id,))
        return [NoteRecord(r[0], r[1], _float(r[2]), r[3], r[4]) for r in rows]

    def add_event(self, session_id: int, event: SessionEvent) -> int:
        """Append a session event. Returns its id."""
        with self._transaction() as c:
            return self._insert_event(c, session_id, event)

    def events(self, session_id: int) -> list[SessionEvent]:
        """A session's events in order."""
        rows = self._conn.execute("SELECT t_s, kind, detail, id FROM session_event WHERE session_id = ? ORDER BY id",
                                  (session_id,))
        return [SessionEvent(*r) for r in rows]

    def session_time_span_utc(self, session_id: int) -> tuple[str, str] | None:
        """First and last wall-clock time (UTC, ISO 8601) at which the session stored a setup,
        a fix decision, a note or an event; None when it stored none of them."""
        r = self._conn.execute(
            "SELECT MIN(u), MAX(u) FROM (SELECT created_utc AS u FROM session_event WHERE session_id = ?1 "
            "UNION ALL SELECT created_utc FROM station_setup WHERE session_id = ?1 "
            "UNION ALL SELECT d.created_utc FROM fix_decision d JOIN fix f ON f.id = d.fix_id WHERE f.session_id = ?1 "
            "UNION ALL SELECT created_utc FROM note WHERE session_id = ?1)", (session_id,)).fetchone()
        return None if r is None or r[0] is None else (str(r[0]), str(r[1]))

    # -- raw and decoded data --------------------------------------------------------------------
    def raw_chunks(self, session_id: int, device: str | None = None) -> list[RawChunk]:
        """Raw bytes of a session (optionally one device), in arrival order."""
        if device is None:
            rows = self._conn.execute("SELECT device, t_host_s, payload FROM raw_chunk WHERE session_id = ? ORDER BY id",
                                      (session_id,))
        else:
            rows = self._conn.execute("SELECT device, t_host_s, payload FROM raw_chunk WHERE session_id = ? AND "
                                      "device = ? ORDER BY id", (session_id, device))
        return [RawChunk(r[0], r[1], bytes(r[2])) for r in rows]

    def record_counts(self, session_id: int) -> list[RecordCount]:
        """Rows stored per raw device and per decoded table."""
        out = [RecordCount("raw_chunk", d, n) for d, n in self._conn.execute(
            "SELECT device, COUNT(*) FROM raw_chunk WHERE session_id = ? GROUP BY device ORDER BY device", (session_id,))]
        for t in ("imu_sample", "odometer_sample", "gauge_sample", "fix"):
            n = self._conn.execute(f"SELECT COUNT(*) FROM {t} WHERE session_id = ?", (session_id,)).fetchone()[0]
            out.append(RecordCount(t, "", int(n)))
        return out

    def append_imu_arrays(self, session_id: int, t_s: np.ndarray, w_rad_s: np.ndarray, f_m_s2: np.ndarray) -> None:
        """Bulk-append IMU samples from arrays (one transaction)."""
        data = np.column_stack([np.asarray(t_s, float), np.asarray(w_rad_s, float), np.asarray(f_m_s2, float)])
        with self._transaction() as c:
            c.executemany("INSERT INTO imu_sample (session_id, t_s, wx_rad_s, wy_rad_s, wz_rad_s, fx_m_s2, fy_m_s2, "
                          "fz_m_s2) VALUES (?, ?, ?, ?, ?, ?, ?, ?)", ((session_id, *r) for r in data.tolist()))

    def append_odometer_arrays(self, session_id: int, t_s: np.ndarray, distance_m: np.ndarray) -> None:
        """Bulk-append odometer readings from arrays."""
        with self._transaction() as c:
            c.executemany("INSERT INTO odometer_sample (session_id, t_s, distance_m) VALUES (?, ?, ?)",
                          ((session_id, t, d) for t, d in zip(np.asarray(t_s, float).tolist(),
                                                              np.asarray(distance_m, float).tolist())))

    def append_gauge_arrays(self, session_id: int, t_s: np.ndarray, gauge_m: np.ndarray) -> None:
        """Bulk-append gauge readings from arrays."""
        with self._transaction() as c:
            c.executemany("INSERT INTO gauge_sample (session_id, t_s, gauge_m) VALUES (?, ?, ?)",
                          ((session_id, t, g) for t, g in zip(np.asarray(t_s, float).tolist(),
                                                              np.asarray(gauge_m, float).tolist())))

    def imu_arrays(self, session_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU samples in time order: t (N,), w (N, 3), f (N, 3)."""
        rows = self._conn.execute("SELECT t_s, wx_rad_s, wy_rad_s, wz_rad_s, fx_m_s2, fy_m_s2, fz_m_s2 FROM imu_sample "
                                  "WHERE session_id = ? ORDER BY t_s, id", (session_id,)).fetchall()
        a = np.array(rows, dtype=float).reshape(-1, 7)
        return a[:, 0].copy(), a[:, 1:4].copy(), a[:, 4:7].copy()

    def odometer_arrays(self, session_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Odometer readings in time order: t (N,), distance (N,)."""
        rows = self._conn.execute("SELECT t_s, distance_m FROM odometer_sample WHERE session_id = ? ORDER BY t_s, id",
                                  (session_id,)).fetchall()
        a = np.array(rows, dtype=float).reshape(-1, 2)
        return a[:, 0].copy(), a[:, 1].copy()

    def gauge_arrays(self, session_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Gauge readings in time order: t (N,), gauge (N,)."""
        rows = self._conn.execute("SELECT t_s, gauge_m FROM gauge_sample WHERE session_id = ? ORDER BY t_s, id",
                                  (session_id,)).fetchall()
        a = np.array(rows, dtype=float).reshape(-1, 2)
        return a[:, 0].copy(), a[:, 1].copy()

    # -- processed results -----------------------------------------------------------------------
    @staticmethod
    def _insert_track(c, session_id: int, kind: str, t_start_s: float, t_end_s: float, track: TrackResult) -> int:
        n = len(track)
        cols = np.column_stack([track.chainage_m, track.enh_m, track.sigma_enh_m, track.lateral_dev_m,
                                track.vertical_dev_m, track.gauge_m, track.cant_m, track.twist_m]).reshape(n, 12)
        run_id = int(c.execute("INSERT INTO processing_run (session_id, kind, t_start_s, t_end_s, created_utc) "
                               "VALUES (?, ?, ?, ?, ?)", (session_id, kind, t_start_s, t_end_s, utc_now())).lastrowid)
        c.executemany("INSERT INTO track_row (run_id, chainage_m, e_m, n_m, h_m, sigma_e_m, sigma_n_m, sigma_h_m, "
                      "lateral_dev_m, vertical_dev_m, gauge_m, cant_m, twist_m) VALUES "
                      "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                      ((run_id, *[_nullable(x) for x in r]) for r in cols.tolist()))
        return run_id

    def add_track(self, session_id: int, kind: str, t_start_s: float, t_end_s: float, track: TrackResult) -> int:
        """Store processed track rows as one processing run. Returns the run id."""
        with self._transaction() as c:
            return self._insert_track(c, session_id, kind, t_start_s, t_end_s, track)

    def add_interval(self, session_id: int, t_start_s: float, t_end_s: float, track: TrackResult,
                     detail: dict) -> int:
        """Store a live interval summary in one transaction: its track rows as an "interval"
        processing run and its ``interval`` event (at ``t_end_s``), whose JSON detail is ``detail``
        with the run id and the interval's times. Returns the run id."""
        with self._transaction() as c:
            run_id = self._insert_track(c, session_id, "interval", t_start_s, t_end_s, track)
            full = {"run_id": run_id, "t_start_s": t_start_s, "t_end_s": t_end_s, **detail}
            self._insert_event(c, session_id, SessionEvent(t_end_s, "interval", json.dumps(full)))
        return run_id

    def interval_summaries(self, session_id: int) -> list[dict]:
        """The live interval summaries that stand, oldest first: the JSON details of the ``interval``
        events (run id, times, seconds, defects, tolerance set, the line shown) without those
        withdrawn by the undo of their closing fix (``interval_undone``, :meth:`decide_fix`)."""
        events = self.events(session_id)
        withdrawn = {json.loads(e.detail)["run_id"] for e in events if e.kind == "interval_undone"}
        return [d for d in (json.loads(e.detail) for e in events if e.kind == "interval")
                if d["run_id"] not in withdrawn]

    def processing_runs(self, session_id: int) -> list[ProcessingRun]:
        """A session's processing runs, oldest first."""
        rows = self._conn.execute(
            "SELECT r.id, r.session_id, r.kind, r.t_start_s, r.t_end_s, r.created_utc, "
            "(SELECT COUNT(*) FROM track_row t WHERE t.run_id = r.id) FROM processing_run r "
            "WHERE r.session_id = ? ORDER BY r.id", (session_id,))
        return [ProcessingRun(*r) for r in rows]

    def track(self, run_id: int) -> TrackResult:
        """The track rows of a processing run, by chainage."""
        rows = self._conn.execute(
            "SELECT chainage_m, e_m, n_m, h_m, sigma_e_m, sigma_n_m, sigma_h_m, lateral_dev_m, vertical_dev_m, "
            "gauge_m, cant_m, twist_m FROM track_row WHERE run_id = ? ORDER BY chainage_m, id", (run_id,)).fetchall()
        a = np.array([[np.nan if x is None else x for x in r] for r in rows], dtype=float).reshape(-1, 12)
        return TrackResult(a[:, 0].copy(), a[:, 1:4].copy(), a[:, 4:7].copy(), a[:, 7].copy(), a[:, 8].copy(),
                           a[:, 9].copy(), a[:, 10].copy(), a[:, 11].copy())

    # -- raw session folder mapping --------------------------------------------------------------
    def import_raw_session(self, name: str, raw: RawSession, *, design: AlignmentRecord | None = None,
                           source_toml: str | None = None) -> SessionRecord:
        """Store a whole raw session (FORMATS.md section 1) as a new session, in one transaction.

        The design alignment, if given, is stored (or reused when the same LandXML text is already
        stored) and linked to the session. Fixes are stored as accepted ("imported").
        """
        _check_name("session name", name)
        with self._transaction() as c:
            if c.execute("SELECT 1 FROM session WHERE name = ?", (name,)).fetchone():
                raise StoreError(f"session {name!r} already exists in project {self.info().name!r}")
            alignment_id = None
            if design is not None:
                r = c.execute("SELECT id FROM alignment WHERE landxml_text = ? ORDER BY id DESC LIMIT 1",
                              (design.landxml_text,)).fetchone()
                alignment_id = int(r[0]) if r else _insert_alignment(c, design)
            sid = int(c.execute(
                "INSERT INTO session (name, created_utc, state, source, meta_json, source_toml, alignment_id) "
                "VALUES (?, ?, 'imported', 'imported', ?, ?, ?)",
                (name, utc_now(), meta_to_json(raw.meta), source_toml, alignment_id)).lastrowid)
            data = np.column_stack([raw.imu_t_s, raw.imu_w_rad_s, raw.imu_f_m_s2])
            c.executemany("INSERT INTO imu_sample (session_id, t_s, wx_rad_s, wy_rad_s, wz_rad_s, fx_m_s2, fy_m_s2, "
                          "fz_m_s2) VALUES (?, ?, ?, ?, ?, ?, ?, ?)", ((sid, *r) for r in data.tolist()))
            c.executemany("INSERT INTO odometer_sample (session_id, t_s, distance_m) VALUES (?, ?, ?)",
                          ((sid, t, d) for t, d in zip(np.asarray(raw.odo_t_s, float).tolist(),
                                                       np.asarray(raw.odo_distance_m, float).tolist())))
            if raw.gauge_t_s is not None and raw.gauge_m is not None:
                c.executemany("INSERT INTO gauge_sample (session_id, t_s, gauge_m) VALUES (?, ?, ?)",
                              ((sid, t, g) for t, g in zip(np.asarray(raw.gauge_t_s, float).tolist(),
                                                           np.asarray(raw.gauge_m, float).tolist())))
            fx = raw.fixes
            for i in range(len(fx)):
                _insert_fix(c, sid, FixRecord(float(fx.t_s[i]), str(fx.point[i]), *map(float, fx.enh_m[i]),
                                              *map(float, fx.sigma_m[i]), accepted=True, reason="imported",
                                              cov_m2=None if fx.cov_m2 is None else tuple(map(float, fx.cov_m2[i]))))
        return self.session(name)

    def survey_start_s(self, session_id: int) -> float | None:
        """Session time where the survey's data begin: the start of the static alignment that
        succeeded (event ``aligned``; later than 0 when the alignment restarted), else None."""
        start = None
        for ev in self.events(session_id):
            if ev.kind == "aligned":
                start = float(json.loads(ev.detail)["static_start_s"])
        return start

    def raw_session(self, name: str) -> tuple[RawSession, str | None]:
        """A stored session as a raw session (accepted fixes only) and its design LandXML text (or None).

        The data before the static alignment that succeeded are left out (:func:`crop_session`), so
        that ``trolley process`` on the exported folder gives the session's final track.
        """
        rec = self.session(name)
        sid = rec.session_id
        t, w, f = self.imu_arrays(sid)
        ot, od = self.odometer_arrays(sid)
        gt, gm = self.gauge_arrays(sid)
        fixes = self.fixes(sid, accepted_only=True)
        fx = Fixes(t_s=np.array([x.t_s for x in fixes], dtype=float),
                   point=np.array([x.point for x in fixes], dtype=object),
                   enh_m=np.array([[x.e_m, x.n_m, x.h_m] for x in fixes], dtype=float).reshape(-1, 3),
                   sigma_m=np.array([[x.sigma_e_m, x.sigma_n_m, x.sigma_h_m] for x in fixes], dtype=float).reshape(-1, 3),
                   # fixes imported from a session folder have no setup: their file is given back as it was,
                   # with the covariance columns if it had them
                   cov_m2=self.fix_covariances(sid, fixes)
                   if any(x.setup_id is not None or x.cov_m2 is not None for x in fixes) else None)
        has_gauge = gt.shape[0] > 0
        raw = RawSession(meta=rec.meta, imu_t_s=t, imu_w_rad_s=w, imu_f_m_s2=f, odo_t_s=ot, odo_distance_m=od,
                         fixes=fx, gauge_t_s=gt if has_gauge else None, gauge_m=gm if has_gauge else None)
        design = self.alignment(rec.alignment_id) if rec.alignment_id is not None else None
        if design is not None and design.alignment_name is not None:
            # the file holds several alignments: session.toml [design] names the one surveyed
            raw = replace(raw, meta=replace(raw.meta, design_alignment_name=design.alignment_name))
        return crop_session(raw, self.survey_start_s(sid)), (design.landxml_text if design else None)


def crop_session(raw: RawSession, t0_s: float | None) -> RawSession:
    """The session without the samples and fixes before ``t0_s`` (a restarted static alignment:
    the data before it belong to no alignment). None, or a time at or before the first IMU
    sample: the session unchanged."""
    if t0_s is None or not np.isfinite(t0_s) or raw.imu_t_s.size == 0 or t0_s <= raw.imu_t_s[0]:
        return raw
    i = raw.imu_t_s >= t0_s
    o = raw.odo_t_s >= t0_s
    g = None if raw.gauge_t_s is None else raw.gauge_t_s >= t0_s
    f = raw.fixes.t_s >= t0_s
    fx = raw.fixes.take(f)
    return replace(raw, imu_t_s=raw.imu_t_s[i], imu_w_rad_s=raw.imu_w_rad_s[i], imu_f_m_s2=raw.imu_f_m_s2[i],
                   odo_t_s=raw.odo_t_s[o], odo_distance_m=raw.odo_distance_m[o], fixes=fx,
                   gauge_t_s=None if g is None else raw.gauge_t_s[g], gauge_m=None if g is None else raw.gauge_m[g])


def _insert_alignment(c: sqlite3.Connection, rec: AlignmentRecord) -> int:
    cur = c.execute("INSERT INTO alignment (file_name, name, landxml_text, element_count, chainage_start_m, "
                    "chainage_end_m, imported_utc) VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (rec.file_name, rec.name, rec.landxml_text, rec.element_count, rec.chainage_start_m,
                     rec.chainage_end_m, rec.imported_utc or utc_now()))
    return int(cur.lastrowid)


def alignment_record_from_text(file_name: str, text: str, rail_spacing_m: float | None = None,
                               alignment_name: str | None = None) -> AlignmentRecord:
    """Read a LandXML design (``trolley.landxml.read_landxml``) into a record that keeps the text verbatim.

    Parameters
    ----------
    file_name, text : the file's name and its text.
    rail_spacing_m : rail spacing for the cant (None: the file's ``gauge``).
    alignment_name : the ``Alignment/@name`` to take from a file holding several.

    Returns
    -------
    AlignmentRecord
        With the reader's notes (skipped elements, tolerated mismatches) in ``notes``.

    Raises
    ------
    trolley.landxml.AlignmentChoiceError : several alignments and no (or an unknown) name.
    trolley.landxml.LandXmlError : the file is not a usable LandXML 1.2 alignment.
    """
    from trolley.landxml import read_landxml

    kwargs = {} if rail_spacing_m is None else {"rail_spacing_m": rail_spacing_m}
    d = read_landxml(text, alignment_name, **kwargs)
    al = d.alignment
    return AlignmentRecord(file_name=file_name, landxml_text=text, name=al.name or Path(file_name).stem,
                           element_count=len(al.horizontal.elements), chainage_start_m=al.start_chainage_m,
                           chainage_end_m=al.end_chainage_m, notes=d.notes)


def _insert_fix(c: sqlite3.Connection, session_id: int, fix: FixRecord) -> int:
    fix_id = int(c.execute(
        "INSERT INTO fix (session_id, t_s, point, e_m, n_m, h_m, sigma_e_m, sigma_n_m, sigma_h_m, setup_id, "
        "cov_en_m2, cov_eh_m2, cov_nh_m2) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (session_id, fix.t_s, fix.point, fix.e_m, fix.n_m, fix.h_m, fix.sigma_e_m, fix.sigma_n_m, fix.sigma_h_m,
         fix.setup_id, *(fix.cov_m2 if fix.cov_m2 is not None else (None, None, None)))).lastrowid)
    c.execute("INSERT INTO fix_decision (fix_id, accepted, reason, created_utc) VALUES (?, ?, ?, ?)",
              (fix_id, int(fix.accepted), fix.reason, utc_now()))
    return fix_id


# ---------------------------------------------------------------------------------------------
# Batched, crash-safe appends
# ---------------------------------------------------------------------------------------------

_RECORD_TABLES: dict[str, tuple[type, str]] = {
    "imu_sample": (ImuRecord, "INSERT INTO imu_sample (session_id, t_s, wx_rad_s, wy_rad_s, wz_rad_s, fx_m_s2, "
                              "fy_m_s2, fz_m_s2) VALUES (?, ?, ?, ?, ?, ?, ?, ?)"),
    "odometer_sample": (OdometerRecord, "INSERT INTO odometer_sample (session_id, t_s, distance_m) VALUES (?, ?, ?)"),
    "gauge_sample": (GaugeRecord, "INSERT INTO gauge_sample (session_id, t_s, gauge_m) VALUES (?, ?, ?)"),
}

_RECORD_ALIASES = {"imu": "imu_sample", "odometer": "odometer_sample", "gauge": "gauge_sample"}


class RecordWriter:
    """Buffered appends of raw bytes and decoded records for one session.

    ``append`` and ``append_records`` only queue; a background thread commits everything queued in
    one transaction at least every ``flush_interval_s`` or as soon as ``max_rows`` rows are queued.
    ``flush()`` commits now; ``close()`` flushes and stops the thread. An error in the background
    commit is raised by the next call.

    Parameters
    ----------
    path : the project's store file.
    session_id : the session the rows belong to.
    flush_interval_s : longest time a queued row waits (at most 1 s is the crash-safety promise).
    max_rows : queued rows that trigger an early commit.
    """

    def __init__(self, path: Path | str, session_id: int, flush_interval_s: float = 0.5, max_rows: int = 5000):
        if not 0.0 < flush_interval_s <= 1.0:
            raise ValueError("flush_interval_s must be in (0, 1] s")
        self.session_id = session_id
        self.flush_interval_s = flush_interval_s
        self.max_rows = max_rows
        self._conn = connect(Path(path), check_same_thread=False)
        self._raw: list[tuple] = []
        self._records: dict[str, list[tuple]] = {t: [] for t in _RECORD_TABLES}
        self._queued = 0
        self._lock = threading.Lock()  # guards the queues
        self._commit_lock = threading.Lock()  # one commit at a time
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self.committed_rows = 0
        self.commits = 0
        self.last_commit_monotonic_s = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"RecordWriter-{session_id}", daemon=True)
        self._thread.start()

    def _check(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise StoreError(f"writing to the project store failed: {err}") from err
        if self._stop.is_set():
            raise StoreError("the record writer is closed")

    def append(self, device: str, t_host_s: float, payload: bytes) -> None:
        """Queue raw bytes read from ``device`` at host time ``t_host_s``."""
        self._check()
        with self._lock:
            self._raw.append((self.session_id, device, float(t_host_s), bytes(payload)))
            self._queued += 1
            full = self._queued >= self.max_rows
        if full:
            self._wake.set()

    def append_records(self, table: str, rows: Iterable) -> None:
        """Queue decoded records (``ImuRecord`` for "imu_sample", ``OdometerRecord`` for "odometer_sample",
        ``GaugeRecord`` for "gauge_sample"; "imu", "odometer" and "gauge" are accepted as well)."""
        self._check()
        table = _RECORD_ALIASES.get(table, table)
        if table not in _RECORD_TABLES:
            raise StoreError(f"unknown record table {table!r} (one of {', '.join(_RECORD_TABLES)})")
        cls, _ = _RECORD_TABLES[table]
        tuples = []
        for r in rows:
            if not isinstance(r, cls):
                raise TypeError(f"{table} takes {cls.__name__} rows, got {type(r).__name__}")
            tuples.append((self.session_id, *dataclasses.astuple(r)))
        with self._lock:
            self._records[table].extend(tuples)
            self._queued += len(tuples)
            full = self._queued >= self.max_rows
        if full:
            self._wake.set()

    def flush(self) -> int:
        """Commit everything queued now. Returns the number of rows committed."""
        with self._commit_lock:
            with self._lock:
                raw, self._raw = self._raw, []
                recs = {t: v for t, v in self._records.items() if v}
                self._records = {t: [] for t in _RECORD_TABLES}
                self._queued = 0
            n = len(raw) + sum(len(v) for v in recs.values())
            if n:
                c = self._conn
                c.execute("BEGIN IMMEDIATE")
                try:
                    if raw:
                        c.executemany("INSERT INTO raw_chunk (session_id, device, t_host_s, payload) VALUES (?, ?, ?, ?)",
                                      raw)
                    for t, v in recs.items():
                        c.executemany(_RECORD_TABLES[t][1], v)
                    c.execute("COMMIT")
                except BaseException:
                    _rollback(c)
                    # put the rows back so nothing is lost; the caller sees the error
                    with self._lock:
                        self._raw[:0] = raw
                        for t, v in recs.items():
                            self._records[t][:0] = v
                        self._queued += n
                    raise
                self.committed_rows += n
                self.commits += 1
            self.last_commit_monotonic_s = time.monotonic()
            return n

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.flush_interval_s)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self.flush()
            except BaseException as e:  # reported to the caller on its next call
                self._error = e

    def close(self) -> None:
        """Flush and stop the background thread (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake.set()
        self._thread.join()
        try:
            self.flush()
        finally:
            self._conn.close()
        if self._error is not None:
            err, self._error = self._error, None
            raise StoreError(f"writing to the project store failed: {err}") from err

    def __enter__(self) -> "RecordWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
