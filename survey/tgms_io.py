"""Reading and writing TGMS recording folders (FORMATS.md section 3), ``truth.csv`` of synthetic
recordings, ``irregularities.csv`` and the tuning-parameter file.

Every reader raises :class:`TgmsFormatError` with a one-line message naming the file, the row and
the column (or the TOML key); writers write to a temporary file in the same folder and
``os.replace`` it at the end, so an interrupted run never leaves a partial file.

Optional keys we added where FORMATS.md is silent (documented in ``docs/tgms.md``):
``[track].start_station_m`` (chainage at encoder count 0, default the alignment start) and
``[camera.*].image_size_px`` (default [648, 488]).
"""
from __future__ import annotations

import os
import re
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from trolley.landxml import landxml_text, parse_landxml
from trolley.numbertext import foreign_character
from trolley.tgms.camera import Camera
from trolley.tgms.config import EncoderSettings, TgmsConfig, TrackSettings
from trolley.tgms.irregularities import empty_gap_m
from trolley.tgms.recording import LaserPoints, Recording

from survey.atomicwrite import write_csv_frame, write_text_atomic
from survey.limits import refuse_unknown
from survey.names import inside
from survey.sessionio import PLAUSIBLE_ABS, implicit_index_problem, line_spans

if TYPE_CHECKING:
    from trolley.tgms.pipeline import TgmsResult

FORMAT = "trolley-tgms/1"
IRREGULARITY_COLUMNS = ["s_m", "gauge_variation_mm", "cross_level_mm", "alignment_mm", "vertical_profile_mm"]


class TgmsFormatError(ValueError):
    """A recording folder or file that does not follow FORMATS.md section 3."""


# ---------------------------------------------------------------------------------------------
# tgms.toml
def _fmt(x) -> str:
    return repr(float(x))


def _mat(m) -> str:
    return "[" + ", ".join("[" + ", ".join(_fmt(v) for v in row) + "]" for row in np.asarray(m)) + "]"


def _vec(v) -> str:
    return "[" + ", ".join(_fmt(x) for x in np.asarray(v).ravel()) + "]"


def tgms_toml_text(config: TgmsConfig) -> str:
    """The ``tgms.toml`` text of a configuration."""
    tr = config.track
    lines = [f'format = "{FORMAT}"', "", "[track]",
             f'rail_profile = "{tr.rail_profile}"',
             f"half_rail_spacing_m = {_fmt(tr.half_rail_spacing_m)}",
             f"rail_inclination = {_fmt(tr.rail_inclination)}",
             f'alignment = "{tr.alignment}"']
    if tr.start_station_m is not None:
        lines.append(f"start_station_m = {_fmt(tr.start_station_m)}")
    lines += ["", "[encoder]", f"pulses_per_rev = {int(config.encoder.pulses_per_rev)}",
              f"wheel_diameter_m = {_fmt(config.encoder.wheel_diameter_m)}",
              "", "[imu]", f"rate_hz = {_fmt(config.imu_rate_hz)}"]
    for side in ("left", "right"):
        c = config.cameras[side]
        lines += ["", f"[camera.{side}]", f"K = {_mat(c.K)}", f"R_tgms_cam = {_mat(c.R_tgms_cam)}",
                  f"t_tgms_cam_m = {_vec(c.t_tgms_cam_m)}", f"distortion = {_vec(c.distortion)}",
                  f"laser_plane = {_vec(c.laser_plane)}",
                  f"image_size_px = [{int(c.image_size_px[0])}, {int(c.image_size_px[1])}]"]
    return "\n".join(lines) + "\n"


def _get(table: dict, key: str, where: str, fname: str, default=None, required: bool = True):
    if key not in table:
        if required:
            raise TgmsFormatError(f"{fname}: missing key {where}.{key}")
        return default
    return table[key]


def _num(table, key, where, fname, default=None, required=True) -> float | None:
    v = _get(table, key, where, fname, default, required)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise TgmsFormatError(f"{fname}: {where}.{key} must be a finite number, got {v!r}")
    return float(v)


def _array(table, key, where, fname, shape, default=None, required=True) -> np.ndarray:
    v = _get(table, key, where, fname, default, required)
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise TgmsFormatError(f"{fname}: {where}.{key} must be numbers of shape {shape}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise TgmsFormatError(f"{fname}: {where}.{key} must be finite numbers of shape {shape}, got shape {a.shape}")
    return a


#: the keys of tgms.toml's tables (FORMATS.md section 3)
TRACK_KEYS = ("rail_profile", "half_rail_spacing_m", "rail_inclination", "alignment", "start_station_m")
CAMERA_KEYS = ("K", "R_tgms_cam", "t_tgms_cam_m", "distortion", "laser_plane", "image_size_px")


def parse_tgms_toml(text: str, fname: str = "tgms.toml") -> TgmsConfig:
    """Configuration from the text of ``tgms.toml``; TgmsFormatError naming the key if invalid."""
    try:
        doc = tomllib.loads(text.removeprefix("\ufeff"))   # (a BOM, as Notepad writes)
    except tomllib.TOMLDecodeError as exc:
        raise TgmsFormatError(f"{fname}: not valid TOML ({exc})") from None
    fmt = doc.get("format")
    if fmt != FORMAT:
        raise TgmsFormatError(f"{fname}: format must be \"{FORMAT}\", got {fmt!r}")
    # a misspelt optional key (distorsion, rail_inclinaton) fell back to its default without a word
    # (bug hunt 2026-11-27)
    refuse_unknown(doc, {"format", "track", "encoder", "imu", "camera"}, "", fname, TgmsFormatError)
    for table, known in (("track", TRACK_KEYS), ("encoder", ("pulses_per_rev", "wheel_diameter_m")),
                         ("imu", ("rate_hz",)), ("camera", ("left", "right"))):
        if isinstance(doc.get(table), dict):
            refuse_unknown(doc[table], known, table, fname, TgmsFormatError)
    for side in ("left", "right"):
        if isinstance(doc.get("camera", {}).get(side), dict):
            refuse_unknown(doc["camera"][side], CAMERA_KEYS, f"camera.{side}", fname, TgmsFormatError)
    tr = _get(doc, "track", "", fname)
    prof = _get(tr, "rail_profile", "track", fname)
    if prof not in ("60E1", "54E1"):
        raise TgmsFormatError(f"{fname}: track.rail_profile must be \"60E1\" or \"54E1\", got {prof!r}")
    track = TrackSettings(rail_profile=prof,
                          half_rail_spacing_m=_num(tr, "half_rail_spacing_m", "track", fname),
                          rail_inclination=_num(tr, "rail_inclination", "track", fname, 40.0, False),
                          alignment=str(_get(tr, "alignment", "track", fname)),
                          start_station_m=_num(tr, "start_station_m", "track", fname, None, False))
    en = _get(doc, "encoder", "", fname)
    ppr = _num(en, "pulses_per_rev", "encoder", fname)
    if ppr != round(ppr):
        # (bug hunt 2026-11-27: 1440.7 became 1440 without a word)
        raise TgmsFormatError(f"{fname}: encoder.pulses_per_rev must be a whole number of pulses, got {ppr!r}")
    enc = EncoderSettings(pulses_per_rev=int(ppr), wheel_diameter_m=_num(en, "wheel_diameter_m", "encoder", fname))
    imu = _get(doc, "imu", "", fname)
    rate = _num(imu, "rate_hz", "imu", fname)
    cams_t = _get(doc, "camera", "", fname)
    cams = {}
    for side in ("left", "right"):
        where = f"camera.{side}"
        if side not in cams_t:
            raise TgmsFormatError(f"{fname}: missing table [{where}]")
        c = cams_t[side]
        size = _array(c, "image_size_px", where, fname, (2,), [648, 488], False)
        cams[side] = Camera(K=_array(c, "K", where, fname, (3, 3)),
                            R_tgms_cam=_array(c, "R_tgms_cam", where, fname, (3, 3)),
                            t_tgms_cam_m=_array(c, "t_tgms_cam_m", where, fname, (3,)),
                            distortion=_array(c, "distortion", where, fname, (4,), [0, 0, 0, 0], False),
                            laser_plane=_array(c, "laser_plane", where, fname, (4,)),
                            image_size_px=(int(size[0]), int(size[1])), name=side)
    cfg = TgmsConfig(track=track, encoder=enc, imu_rate_hz=rate, cameras=cams)
    try:
        cfg.validate()
    except ValueError as exc:
        raise TgmsFormatError(f"{fname}: {exc}") from None
    return cfg


# ---------------------------------------------------------------------------------------------
# CSV
#: Largest plausible |value| of the TGMS columns that the raw-session reader does not know
#: (sessionio.PLAUSIBLE_ABS has the IMU ones): an encoder count beyond 1e12 (a 1440-pulse wheel
#: over 1.8 million km) or a pixel far outside any image is a corrupt cell, not a measurement.
_TGMS_PLAUSIBLE_ABS = {"count": 1e12, "frame": 1e12, "u_px": 1e5, "v_px": 1e5, "s_m": 1e8}


def _cells_in_row(path: Path, row: int) -> int:
    """How many comma-separated cells row ``row`` (1-based, as an editor shows it) of a file has;
    read only on the way to an error message."""
    import csv
    import itertools

    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        rec = next(itertools.islice(csv.reader(fh), row - 1, None), [])
    return len(rec)


def _first_used_line(path: Path) -> tuple[str, int]:
    """The first line that is not blank (pandas skips blank lines) and its row number (1-based, as
    an editor shows it); ("", 1) for an empty file."""
    with open(path, "rb") as fh:
        for row, raw in enumerate(fh, start=1):
            text = raw.decode("utf-8-sig" if row == 1 else "utf-8", errors="replace")
            if text.strip():
                return text.rstrip("\r\n"), row
    return "", 1


def _comment_line_text(name: str, row: int, text: str, columns: list[str], before_header: bool) -> str:
    """The message of a line starting with '#': these formats have no comment lines (FORMATS.md
    section 3, docs/inservice.md "Recording format"), and the message says so, not "a decimal
    comma?". Refused rather than skipped: the formats are exchange formats read exactly as
    written, and a logger's comment may say what the columns do not (units, a clock offset)."""
    shown = text.strip()
    shown = repr(shown if len(shown) <= 40 else shown[:37] + "...")
    if before_header and columns and columns[0] in text.lstrip().lstrip("#").split(",")[0].strip():
        return f"{name}: row {row}: the header starts with '#' ({shown}): write the column names without it"
    where = "the column names come first" if before_header else "every row after the header is data"
    return (f"{name}: row {row}: a comment line ({shown}){' above the header' if before_header else ''}; the "
            f"format has no comment lines, {where} (delete the line)")


def _read_csv(path: Path, columns: list[str], *, integer: tuple[str, ...] = (),
              monotonic: str | None = "t_s", strict: bool = False, min_rows: int = 1) -> dict[str, np.ndarray]:
    name = path.name
    if not path.exists():
        raise TgmsFormatError(f"{name}: file not found in {path.parent}")
    head, head_row = _first_used_line(path)
    if head.lstrip().startswith("#"):
        # pandas took the comment for the header (one column) and answered the first data row with
        # "6 cells, the header has 1 columns (a decimal comma?)"
        raise TgmsFormatError(_comment_line_text(name, head_row, head, columns, before_header=True))
    for sep, said in ((";", "';'"), ("\t", "tabs")):
        if sep in head and "," not in head:
            # a spreadsheet saved with its locale's list separator (and, likely, decimal commas), or
            # a logger's tab-separated text: "missing column t_s" though t_s was in the header
            raise TgmsFormatError(f"{name}: row 1: the columns are separated by {said}: save the file as "
                                  "comma-separated CSV with decimal points (0.5)")
    try:
        # low_memory=False: a text cell in a long numeric column is reported below, not as a DtypeWarning
        df = pd.read_csv(path, skipinitialspace=True, low_memory=False)
    except Exception as exc:  # pandas raises several types for broken CSV
        text = " ".join(str(exc).split())
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
        if m:
            raise TgmsFormatError(f"{name}: row {m[2]}: {m[3]} cells, the header has {m[1]} columns (a decimal "
                                  "comma? use a point: 0.5)") from None
        raise TgmsFormatError(f"{name}: cannot read as CSV ({text})") from None
    problem = implicit_index_problem(path, df)
    if problem:
        raise TgmsFormatError(problem)
    line = _data_row_lines(path, len(df))
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise TgmsFormatError(f"{name}: missing column {missing[0]}")
    if len(df) < min_rows:
        raise TgmsFormatError(f"{name}: {len(df)} data row(s), at least {min_rows} needed" if len(df)
                              else f"{name}: no data rows")
    out = {}
    for c in columns:
        col = df[c]
        if pd.api.types.is_numeric_dtype(col):
            vals = col.to_numpy(dtype=float).copy()
        else:
            vals = pd.to_numeric(col.astype(str).str.strip(), errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(vals)
        if bad.any():
            i = int(np.argmax(bad))
            # (before "a row cut short?": a comment line is one cell wide)
            if str(df.iloc[i, 0]).lstrip().startswith("#"):
                raise TgmsFormatError(_comment_line_text(name, int(line[i]), ",".join(
                    str(x) for x in df.iloc[i] if not pd.isna(x)), columns, before_header=False))
            if pd.isna(col.iloc[i]) and _cells_in_row(path, int(line[i])) < len(df.columns):
                raise TgmsFormatError(f"{name}: row {line[i]}: {_cells_in_row(path, int(line[i]))} cells, the "
                                      f"header has {len(df.columns)} columns (a row cut short?)")
            cell = str(col.iloc[i])
            foreign = foreign_character(cell)
            raise TgmsFormatError(f"{name}: row {line[i]}, column {c}: not a finite number ({cell!r})"
                                  + (f": {foreign}" if foreign else ""))
        limit = PLAUSIBLE_ABS.get(c, _TGMS_PLAUSIBLE_ABS.get(c, np.inf))
        far = np.abs(vals) > limit
        if far.any():
            i = int(np.argmax(far))
            raise TgmsFormatError(f"{name}: row {line[i]}, column {c}: {float(vals[i]):g} is not a plausible value "
                                  f"(|{c}| <= {limit:g})")
        if c in integer:
            if np.any(vals != np.round(vals)):
                i = int(np.argmax(vals != np.round(vals)))
                raise TgmsFormatError(f"{name}: row {line[i]}, column {c}: not an integer")
            vals = vals.astype(np.int64)
        out[c] = vals
    if monotonic is not None:
        d = np.diff(out[monotonic])
        back = d <= 0 if strict else d < 0
        if back.any():
            i = int(np.argmax(back)) + 1
            what = (f"repeats the previous row's {out[monotonic][i]:g} (a duplicated row?)" if d[i - 1] == 0
                    else "goes backwards")
            label = "time" if monotonic == "t_s" else "chainage"
            raise TgmsFormatError(f"{name}: row {line[i]}, column {monotonic}: {label} {what}")
    out["_line"] = line
    return out


def _data_row_lines(path: Path, n: int) -> np.ndarray:
    """The file's line numbers (1-based, as an editor shows them) of the ``n`` data rows pandas read:
    blank and whitespace-only lines are skipped by pandas but counted by the editor."""
    try:
        data = np.frombuffer(path.read_bytes(), np.uint8)
    except OSError:
        data = np.zeros(0, np.uint8)
    used = np.flatnonzero(line_spans(data)[2]) + 1
    rows = used[1:]                  # after the header
    if rows.size != n:               # (quoted line breaks: fall back to counting data rows)
        rows = np.arange(n) + 2
    return rows


def read_recording(folder: str | os.PathLike) -> Recording:
    """Read a TGMS recording folder (FORMATS.md section 3).

    Raises
    ------
    TgmsFormatError : naming the file and row/column or key at fault.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise TgmsFormatError(f"{folder}: not a folder")
    toml_path = folder / "tgms.toml"
    if not toml_path.exists():
        raise TgmsFormatError(f"tgms.toml: file not found in {folder}")
    try:
        text = toml_path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise TgmsFormatError(f"{toml_path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    cfg = parse_tgms_toml(text)
    try:
        al_path = inside(folder, cfg.track.alignment, f"{toml_path}: key track.alignment")
    except ValueError as exc:
        raise TgmsFormatError(str(exc)) from None
    if not al_path.is_file():
        raise TgmsFormatError(f"tgms.toml: track.alignment names {cfg.track.alignment!r}, not found in {folder}")
    try:
        alignment = parse_landxml(al_path.read_text(encoding="utf-8"))
    except ValueError as exc:  # UnicodeDecodeError included
        raise TgmsFormatError(f"{al_path}: {exc}") from None
    s0 = cfg.track.start_station_m
    if s0 is not None and not (alignment.start_chainage_m <= s0 <= alignment.end_chainage_m):
        raise TgmsFormatError(f"{toml_path}: key track.start_station_m: {s0:g} m is outside the alignment "
                              f"{al_path.name} ({alignment.start_chainage_m:g} .. {alignment.end_chainage_m:g} m)")
    imu = _read_csv(folder / "imu.csv", ["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2"],
                    strict=True, min_rows=2)
    _check_imu_sampling(imu, cfg.imu_rate_hz)
    enc = _read_csv(folder / "encoder.csv", ["t_s", "count"], integer=("count",), min_rows=2)
    back = np.diff(enc["count"]) < 0
    if back.any():
        # the kinematics run one way along the track (bug hunt 2026-11-26: a reversed encoder
        # ended in "zero-size array to reduction operation fmin")
        i = int(np.argmax(back)) + 1
        raise TgmsFormatError(f"encoder.csv: row {enc['_line'][i]}, column count: the count goes backwards "
                              f"({int(enc['count'][i])} after {int(enc['count'][i - 1])}): the vehicle must run one "
                              "way, with its encoder counting up")
    _check_encoder_on_alignment(enc, cfg, alignment, al_path.name)
    lasers, raw = {}, {}
    for side in ("left", "right"):
        d = _read_csv(folder / f"laser_{side}.csv", ["frame", "t_s", "u_px", "v_px"], integer=("frame",))
        f = d["frame"]
        if np.any(np.diff(f) < 0):
            i = int(np.argmax(np.diff(f) < 0)) + 1
            raise TgmsFormatError(f"laser_{side}.csv: row {d['_line'][i]}, column frame: frame number goes backwards")
        if f.min() < 0:
            raise TgmsFormatError(f"laser_{side}.csv: row {d['_line'][int(np.argmin(f))]}, column frame: negative "
                                  "frame number")
        raw[side] = d
        lasers[side] = LaserPoints(frame=f, t_s=d["t_s"], u_px=d["u_px"], v_px=d["v_px"])
    _check_frame_times(raw, lasers)
    _check_time_overlap({"imu.csv": imu["t_s"], "encoder.csv": enc["t_s"],
                         "laser_left.csv and laser_right.csv": np.concatenate([raw[s]["t_s"] for s in raw])})
    return Recording(config=cfg, alignment=alignment, imu_t_s=imu["t_s"],
                     imu_w_rad_s=np.column_stack([imu["wx_rad_s"], imu["wy_rad_s"], imu["wz_rad_s"]]),
                     imu_f_m_s2=np.column_stack([imu["fx_m_s2"], imu["fy_m_s2"], imu["fz_m_s2"]]),
                     enc_t_s=enc["t_s"], enc_count=enc["count"], lasers=lasers)


#: how far the encoder's nominal stations may run outside the alignment: 1 m plus this share of the
#: distance ridden (an encoder scale error the odometry corrects)
ENCODER_OFF_ALIGNMENT_SHARE = 0.01


def _check_encoder_on_alignment(enc: dict, cfg: TgmsConfig, alignment, al_name: str) -> None:
    """The stations the encoder gives (start_station_m + count x metres per count) lie on the
    design alignment: beyond its ends the design is extrapolated as a straight line (bug hunt
    2026-11-27: a ride 110 m past the end gave exit 0 and 32 mm of cross-level error; a count
    starting at 1000000 ended in an internal IndexError)."""
    s0 = cfg.track.start_station_m if cfg.track.start_station_m is not None else alignment.start_chainage_m
    mpc = cfg.encoder.metres_per_count
    s = s0 + enc["count"] * mpc
    tol = 1.0 + ENCODER_OFF_ALIGNMENT_SHARE * float(s[-1] - s[0])
    lo, hi = alignment.start_chainage_m, alignment.end_chainage_m
    out = (s < lo - tol) | (s > hi + tol)
    if out.any():
        i = int(np.argmax(out))
        side = "before the start" if s[i] < lo else "beyond the end"
        raise TgmsFormatError(
            f"encoder.csv: row {enc['_line'][i]}, column count: count {int(enc['count'][i])} puts the TGMS at "
            f"{s[i]:.6g} m ({s0:g} m at count 0 + {mpc:.6g} m per count), {side} of the alignment {al_name} "
            f"({lo:g} .. {hi:g} m): the design must cover the ride; check tgms.toml track.start_station_m, "
            "encoder.wheel_diameter_m and pulses_per_rev, and that the count is 0 at start_station_m")


#: largest gap in imu.csv, in sample periods: the strapdown solution has nothing to bridge it with
#: (bug hunt 2026-11-26: 0.1 s of rows deleted raised the cross-level error from 0.032 to 0.217 mm
#: with exit 0, and 1 s to 2.03 mm)
IMU_GAP_PERIODS = 3.0
#: how far the samples' rate may lie from tgms.toml [imu] rate_hz, relative
IMU_RATE_TOLERANCE = 0.02


def _check_imu_sampling(imu: dict, rate_hz: float) -> None:
    """imu.csv at tgms.toml's rate and without gaps; the refusal names the row or the key."""
    dt = np.diff(imu["t_s"])
    step = float(np.median(dt))
    if abs(step * rate_hz - 1.0) > IMU_RATE_TOLERANCE:
        raise TgmsFormatError(f"tgms.toml: imu.rate_hz = {rate_hz:g}, but the samples of imu.csv are {step:.6g} s "
                              f"apart ({1.0 / step:.6g} Hz): column t_s in seconds?")
    gap = dt > IMU_GAP_PERIODS * step
    if gap.any():
        i = int(np.argmax(gap))
        raise TgmsFormatError(f"imu.csv: row {imu['_line'][i + 1]}, column t_s: a gap of {dt[i]:.6g} s after "
                              f"{imu['t_s'][i]:.6g} s ({dt[i] / step:.0f} sample periods): the IMU must be "
                              "continuous")


#: how far apart in time two rows of one frame number may be, in camera frame periods: both
#: cameras are triggered together, rows with the same frame number are the same instant (docs/tgms.md)
#: (bug hunt: laser_right.csv with every frame number one too high gave exit 0 and 13x
#: the gauge error; its t_s were never read, so 0.5 s added to them changed nothing)
FRAME_TIME_TOLERANCE = 0.1


def _frame_starts(frame: np.ndarray) -> np.ndarray:
    """Index of the first row of each frame of a laser file (its frames are non-decreasing)."""
    return np.flatnonzero(np.r_[True, np.diff(frame) != 0])


def frame_period_s(lasers: dict[str, LaserPoints]) -> float:
    """Camera frame period, s: the median time per frame number between consecutive frames of the
    laser files (dropped frames do not bias it); nan with fewer than two frames."""
    steps = []
    for lp in lasers.values():
        first = _frame_starts(lp.frame)
        steps.append(np.diff(lp.t_s[first]) / np.diff(lp.frame[first]))
    steps = np.concatenate(steps)
    return float(np.median(steps)) if steps.size else float("nan")


def _check_frame_times(raw: dict[str, dict], lasers: dict[str, LaserPoints]) -> None:
    """Rows with the same frame number, in one laser file or in both, have the same t_s (to
    :data:`FRAME_TIME_TOLERANCE` frame periods); the refusal names the file, row and frame."""
    period = frame_period_s(lasers)
    tol = FRAME_TIME_TOLERANCE * period if np.isfinite(period) else 0.0
    same = "rows with the same frame number are the same instant (both cameras are triggered together)"
    per = {}
    for side, d in raw.items():
        first = _frame_starts(d["frame"])
        t_frame = d["t_s"][first]
        off = np.abs(d["t_s"] - t_frame[np.cumsum(np.r_[False, np.diff(d["frame"]) != 0])]) > tol
        if off.any():
            i = int(np.argmax(off))
            j = first[np.searchsorted(first, i, side="right") - 1]
            raise TgmsFormatError(f"laser_{side}.csv: row {d['_line'][i]}, column t_s: frame {int(d['frame'][i])} at "
                                  f"{d['t_s'][i]:.6g} s, but its row {d['_line'][j]} says {d['t_s'][j]:.6g} s: {same}")
        per[side] = (d["frame"][first], t_frame, d["_line"][first])
    (fl, tl, ll), (fr, tr, lr) = per["left"], per["right"]
    _, il, ir = np.intersect1d(fl, fr, assume_unique=True, return_indices=True)
    off = np.abs(tr[ir] - tl[il]) > tol
    if off.any():
        k = int(np.argmax(off))       # the first frame in both files, so the first such row of each
        a, b = il[k], ir[k]
        n = f"{abs(tr[b] - tl[a]) / period:.3g}" if period > 0 else ""
        apart = f", {n} frame period{'' if n == '1' else 's'} apart" if n else ""
        raise TgmsFormatError(f"laser_right.csv: row {lr[b]}, column t_s: frame {int(fr[b])} at {tr[b]:.6g} s, but "
                              f"laser_left.csv row {ll[a]} has it at {tl[a]:.6g} s{apart}: {same}; a frame number or "
                              "a time is off in one of the files")


#: camera frames may lie this far outside the IMU's and the encoder's time (their last samples
#: need not be at the same instant), s
CAMERA_SPAN_TOLERANCE_S = 0.1


def _check_time_overlap(times: dict[str, np.ndarray]) -> None:
    """The IMU, the encoder and the cameras share some time (bug hunt: laser files
    100 s late ended in "zero-size array to reduction operation fmin"), and every camera frame
    lies within the IMU's and the encoder's time: a frame outside cannot be placed along the track
    or levelled (an encoder.csv cut at 15 s of a 26 s ride gave exit 0, an output ending at
    89.5 m and 2.2 mm of cross-level error). The camera files are the last entry of ``times``."""
    span = {k: (float(np.min(t)), float(np.max(t))) for k, t in times.items()}
    late = max(span, key=lambda k: span[k][0])
    early = min(span, key=lambda k: span[k][1])
    if late != early and span[late][0] >= span[early][1]:
        verb = "start" if " and " in late else "starts"
        raise TgmsFormatError(f"{late} {verb} at {span[late][0]:.6g} s (column t_s), when {early} has ended "
                              f"({span[early][1]:.6g} s): the files share no time; their t_s must be seconds on one "
                              "clock")
    cams = list(span)[-1]
    c0, c1 = span[cams]
    for name, (a, b) in list(span.items())[:-1]:
        if c1 > b + CAMERA_SPAN_TOLERANCE_S or c0 < a - CAMERA_SPAN_TOLERANCE_S:
            where = (f"run to {c1:.6g} s and {name} ends at {b:.6g} s" if c1 > b + CAMERA_SPAN_TOLERANCE_S
                     else f"begin at {c0:.6g} s and {name} at {a:.6g} s")
            raise TgmsFormatError(f"{cams} {where} (column t_s): camera frames outside the {name} record cannot be "
                                  f"placed along the track; the files must cover one ride (a cut or shorter "
                                  f"{name}? give it whole, or cut the camera files to its time)")


#: share of empty cells of irregularities.csv above which ``process`` warns even when no other
#: warning says why (bug hunt: 5 Hz cameras at 10 m/s left 784 of 793 cells empty
#: without a word)
EMPTY_SHARE_WARNING = 0.5


def process_warnings(rec: Recording, res: TgmsResult, step_m: float) -> list[str]:
    """What ``trolley tgms process`` must tell about a run that went through but measured less
    than the recording promised: a camera file without the frames the other one has (its end cut
    off, a stretch lost), camera frames too far apart along the track for the output step, or most
    cells empty for another reason (frames flagged). One line each, naming the file and the
    chainage and time lost."""
    out = []
    gap = empty_gap_m(step_m)
    n = len(res.vision.frame)
    s = res.frames.s_m                       # per frame number; NaN: no station (standing, outside the IMU)
    has = {side: np.bincount(lp.frame, minlength=n)[:n] > 0 for side, lp in rec.lasers.items()}
    seen = np.flatnonzero(has["left"] | has["right"])
    for side, other in (("left", "right"), ("right", "left")):
        missing = ~has[side][seen] & has[other][seen]
        edges = np.flatnonzero(np.diff(np.r_[0, missing.astype(np.int8), 0]))
        lost = []
        for a, b in zip(edges[::2], edges[1::2]):        # runs of the other camera's frames only
            f = seen[a:b]
            if np.isfinite(s[f]).any() and np.nanmax(s[f]) - np.nanmin(s[f]) >= gap:
                lost.append((f, np.nanmin(s[f]), np.nanmax(s[f])))
        if lost:
            t = res.vision.t_s
            shown = "; ".join(f"frames {f[0]}-{f[-1]} (t_s {t[f[0]]:.6g}-{t[f[-1]]:.6g} s, s {lo:.1f}-{hi:.1f} m)"
                              for f, lo, hi in lost[:3])
            more = f"; and {len(lost) - 3} more stretches" if len(lost) > 3 else ""
            g = res.grid.s_m
            n_cells = sum(int(((g >= lo) & (g <= hi)).sum()) for _, lo, hi in lost)
            out.append(f"laser_{side}.csv has no rows for {shown}{more}, which laser_{other}.csv has: no {side}-rail "
                       f"profile there; those {n_cells} cells of irregularities.csv are empty")
    # camera frames farther apart than the grid interpolates across: the cells between them are
    # empty. A spacing between one step and this gap fills every cell by interpolation, so it is not
    # warned about (the tests' 40 Hz ride at 12 m/s has 0.3 m between frames on the 0.25 m grid).
    fs = s[seen]
    both = np.isfinite(fs[1:]) & np.isfinite(fs[:-1])
    spacing = float(np.median(np.diff(fs)[both])) if both.any() else 0.0
    cells = np.max([np.isnan(getattr(res.grid, f"{name}_m")).sum() for name in res.grid.NAMES])
    total = len(res.grid.s_m)
    if spacing > gap:
        rate = 1.0 / float(np.median(np.diff(res.vision.t_s[seen])[both]))    # of the frames in the files
        out.append(f"the camera frames are {spacing:.3g} m apart along the track (median; {rate:.3g} Hz at "
                   f"{spacing * rate:.3g} m/s), more than the {gap:g} m across which irregularities.csv "
                   f"interpolates: {cells} of {total} cells are empty; record at {spacing * rate / gap:.3g} Hz or "
                   f"more, ride at {gap * rate:.3g} m/s or less, or use --step-m {spacing / 2:.3g} or more")
    else:
        # (not with frames too far apart everywhere: that warning says why the cells are empty)
        out += _both_cameras_lost(res, seen, gap)
    if not out and cells > EMPTY_SHARE_WARNING * total:
        ok = res.vision.ok[seen]
        out.append(f"{cells} of {total} cells of irregularities.csv ({100.0 * cells / total:.0f} %) are empty (no "
                   f"usable frame within {gap:g} m): {int((~ok).sum())} of {ok.size} camera frames were flagged by "
                   "the profile fit (too few laser points, a poor fit, no gauge face; docs/tgms.md, Pipeline 1)")
    return out + _configuration_mismatch(rec, res)


#: |encoder scale error| fitted by the odometry above which process warns: a measuring wheel is off
#: by ~0.1 % (wear, diameter tolerance); a start station a few metres off is absorbed as a scale
#: error by the fit, which keeps start_station_m fixed (bug hunt 2026-11-27: 5 m off on a 200 m
#: ride gave k = -3.1 %, 1.4 mm of cross-level error, exit 0 and no word)
ODOMETRY_SCALE_WARNING = 0.005
#: |median of (right - left fitted rail angle) / 2| above which process warns, rad: both heads lean
#: more or less towards the track centre than tgms.toml's rail_inclination and rail_profile say
#: (bug hunt 2026-11-27: rail_inclination = 0 for 1:40 rails gave a 0.88 mm gauge bias, 54E1 for
#: 60E1 rails 0.46 mm, both silent; the half-difference was 0.025 and 0.009 rad, 1e-4 when right)
RAIL_TILT_WARNING_RAD = 0.008


def _configuration_mismatch(rec: Recording, res: TgmsResult) -> list[str]:
    """Warnings for tgms.toml values that the measurements contradict: an encoder scale the
    odometry had to stretch implausibly far (a wrong start station or wheel diameter), and rail
    heads fitted at another inclination than the configured one (a wrong rail_inclination or
    rail_profile: a constant gauge bias that no band-pass shows)."""
    out = []
    k = float(getattr(res.odometry, "scale_error", float("nan")))
    if np.isfinite(k) and abs(k) > ODOMETRY_SCALE_WARNING:
        sk = float(res.odometry.sigma_scale_error)
        out.append(f"the odometry fitted an encoder scale error of {100 * k:+.2f} % (+-{100 * sk:.2f} %), more than a "
                   f"measuring wheel is off ({100 * ODOMETRY_SCALE_WARNING:g} %): check tgms.toml "
                   "track.start_station_m (the chainage at count 0, taken as exact) and encoder.wheel_diameter_m; "
                   "the stations and the irregularities near curves and cant ramps are likely wrong")
    tr = rec.config.track
    half = 0.5 * (res.vision.right.angle_rad - res.vision.left.angle_rad)
    half = half[np.isfinite(half)]
    if half.size >= 20:
        m = float(np.median(half))
        if abs(m) > RAIL_TILT_WARNING_RAD:
            beta = (np.arctan(1.0 / tr.rail_inclination) if tr.rail_inclination else 0.0) - m
            seen = f"1:{1.0 / np.tan(beta):.0f}" if beta > 1e-3 else ("upright" if abs(beta) <= 1e-3 else "outwards")
            said = f"1:{tr.rail_inclination:g}" if tr.rail_inclination else "upright (0)"
            out.append(f"the rail heads the cameras see lean {abs(m) * 1e3:.0f} mrad {'more' if m < 0 else 'less'} "
                       f"towards the track centre than tgms.toml says (track.rail_inclination {said}, rail_profile "
                       f"{tr.rail_profile}; seen as if {seen}): the gauge variation carries a constant bias; check "
                       "track.rail_inclination and track.rail_profile")
    return out


def _both_cameras_lost(res: TgmsResult, seen: np.ndarray, gap: float) -> list[str]:
    """Warnings for runs of frame numbers that neither laser file has, over at least ``gap`` m of
    track between the frames either side (bug hunt 2026-11-27: both cameras silent for 2 s, 18.7 m,
    left 76 empty cells without a word; only one camera's loss was warned about)."""
    s = res.frames.s_m
    if seen.size < 2:
        return []
    jumps = np.flatnonzero(np.diff(seen) > 1)
    a, b = seen[jumps], seen[jumps + 1]      # the last frame before each gap and the first after it
    wide = np.isfinite(s[a]) & np.isfinite(s[b]) & (s[b] - s[a] >= gap)
    a, b = a[wide], b[wide]
    if not a.size:
        return []
    t = res.vision.t_s
    g = res.grid.s_m                         # sorted: the cells strictly inside each gap by bisection
    shown = "; ".join(f"frames {i + 1}-{j - 1} (t_s {t[i]:.6g}-{t[j]:.6g} s, s {s[i]:.1f}-{s[j]:.1f} m)"
                      for i, j in zip(a[:3], b[:3]))
    more = f"; and {a.size - 3} more stretches" if a.size > 3 else ""
    n_cells = int(np.sum(np.searchsorted(g, s[b], "left") - np.searchsorted(g, s[a], "right")))
    return [f"laser_left.csv and laser_right.csv both have no rows for {shown}{more}: no rail profile there; "
            f"those {n_cells} cells of irregularities.csv are empty"]


def write_recording(folder: str | os.PathLike, rec: Recording) -> None:
    """Write a recording folder (creates the folder; every file written atomically)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder / rec.config.track.alignment, landxml_text(rec.alignment))
    w, f = rec.imu_w_rad_s, rec.imu_f_m_s2
    write_csv_frame(folder / "imu.csv", pd.DataFrame({
        "t_s": rec.imu_t_s, "wx_rad_s": w[:, 0], "wy_rad_s": w[:, 1], "wz_rad_s": w[:, 2],
        "fx_m_s2": f[:, 0], "fy_m_s2": f[:, 1], "fz_m_s2": f[:, 2]}), "%.9g")
    write_csv_frame(folder / "encoder.csv", pd.DataFrame({"t_s": rec.enc_t_s, "count": rec.enc_count}), "%.6f")
    for side, lp in rec.lasers.items():
        df = pd.DataFrame({"frame": lp.frame, "t_s": np.round(lp.t_s, 6),
                           "u_px": np.round(lp.u_px, 3), "v_px": np.round(lp.v_px, 3)})
        write_csv_frame(folder / f"laser_{side}.csv", df)
    # tgms.toml last: a folder without it is not a recording
    write_text_atomic(folder / "tgms.toml", tgms_toml_text(rec.config))


TRUTH_COLUMNS = ["s_m", "gauge_variation_mm", "cross_level_mm", "alignment_mm", "vertical_profile_mm",
                 "t_s", "r_y_m", "r_z_m", "roll_rad", "pitch_rad", "yaw_rad"]


def write_truth(path: str | os.PathLike, truth) -> None:
    """Write ``truth.csv`` of a synthetic recording (columns :data:`TRUTH_COLUMNS`)."""
    write_csv_frame(Path(path), pd.DataFrame({c: getattr(truth, c) for c in TRUTH_COLUMNS}), "%.9g")


def read_truth(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Columns of ``truth.csv`` as arrays."""
    return _read_csv(Path(path), TRUTH_COLUMNS, monotonic="s_m", strict=True)


def write_irregularities(path: str | os.PathLike, columns: dict[str, np.ndarray]) -> None:
    """Write ``irregularities.csv``: the FORMATS.md columns first, then any extra (sigma) columns;
    NaN cells are written empty."""
    df = pd.DataFrame(columns)
    order = IRREGULARITY_COLUMNS + [c for c in df.columns if c not in IRREGULARITY_COLUMNS]
    write_csv_frame(Path(path), df[order], "%.4f")


def read_irregularities(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read ``irregularities.csv`` (empty cells become NaN)."""
    path = Path(path)
    df = pd.read_csv(path)
    missing = [c for c in IRREGULARITY_COLUMNS if c not in df.columns]
    if missing:
        raise TgmsFormatError(f"{path.name}: missing column {missing[0]}")
    return {c: df[c].to_numpy(dtype=float).copy() for c in df.columns}
