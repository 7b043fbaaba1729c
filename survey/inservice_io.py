"""Reading and writing in-service recordings (docs/inservice.md "Recording format") and their truth.csv.

A recording folder holds ``inservice.toml`` (vehicle nominal parameters, run, sensors) and
``sensors.csv`` (wheelset lateral acceleration and yaw rate, bogie frame lateral acceleration:
the measurements of Munoz 2021 Eq. 8). The true alignment is kept OUTSIDE the folder, in a
``truth.csv`` next to it, so that processing cannot see it.

Signs: the files follow the project's FRD convention (docs/conventions.md): lateral acceleration
and alignment positive to the RIGHT, yaw rate positive clockwise seen from above (about z down),
curvature positive for a right turn. Inside the code (``trolley.inservice``) the paper's track
frame is used (y left, yaw counter-clockwise, curvature left positive); this module converts, once,
and its readers return internal signs.

Readers raise :class:`InserviceFormatError` naming the file, the row and the column (or the TOML
key); writers write each file atomically (temporary file + os.replace, the helpers of
``survey.tgms_io``), so an interrupted run never leaves a partial file.
"""
from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from survey.atomicwrite import write_csv_frame, write_text_atomic
from survey.limits import refuse_unknown
from survey.tgms_io import TgmsFormatError, _num, _read_csv

FORMAT = "trolley-inservice/1"
SENSOR_COLUMNS = ["t_s", "s_m", "speed_m_s", "wheelset_ay_m_s2", "wheelset_wz_rad_s", "frame_ay_m_s2"]
TRUTH_COLUMNS = ["s_m", "alignment_m", "vertical_m", "curvature_1_m"]
#: [vehicle] keys of inservice.toml -> keys of VehicleParameters.nominal() (model.ModelParameters)
VEHICLE_KEYS = {"m_wheelset_kg": "m", "izz_wheelset_kg_m2": "I", "half_contact_spacing_m": "l",
                "half_primary_spacing_m": "ls", "conicity": "conicity", "r0_m": "r0",
                "supported_mass_kg": "mf", "f11_n": "f11", "f22_n": "f22", "f23_n_m": "f23", "f33_n_m2": "f33",
                "kx_primary_n_m": "kx", "cx_primary_n_s_m": "cx", "ky_primary_n_m": "ky",
                "cy_primary_n_s_m": "cy"}
#: further [vehicle] keys (geometry of the whole car)
VEHICLE_EXTRA_KEYS = ("half_wheelbase_m", "half_bogie_spacing_m", "m_frame_kg", "m_body_kg")
#: optional [vehicle] keys of the bogie design model (trolley.inservice.bogie; per bogie) -> its parameter names
BOGIE_KEYS = {"izz_frame_kg_m2": "If", "ky_secondary_n_m": "ky_s", "cy_secondary_n_s_m": "cy_s",
              "kyaw_secondary_n_m_rad": "k_yaw_s", "cyaw_secondary_n_m_s_rad": "c_yaw_s"}


#: [vehicle] values that may be 0 (spin creep, springs and dampers); every other one must be > 0
MAY_BE_ZERO = frozenset({"f23_n_m", "f33_n_m2", "kx_primary_n_m", "cx_primary_n_s_m", "ky_primary_n_m",
                         "cy_primary_n_s_m", "ky_secondary_n_m", "cy_secondary_n_s_m", "kyaw_secondary_n_m_rad",
                         "cyaw_secondary_n_m_s_rad"})
#: largest design curvature of a recording, 1/m (R 100 m, as `trolley inservice simulate` allows)
MAX_CURVATURE_1_M = 0.01


class InserviceFormatError(ValueError):
    """A recording folder or truth file that does not follow docs/inservice.md."""


@dataclass
class InserviceRecording:
    """A recording in internal signs (y left, yaw counter-clockwise, curvature left positive).

    Attributes
    ----------
    nominal : nominal vehicle parameters, keys of ``VehicleParameters.nominal()`` (SI).
    vehicle_extra : half_wheelbase_m, half_bogie_spacing_m, m_frame_kg, m_body_kg, and the keys of
        :data:`BOGIE_KEYS` when the file has all of them.
    speed_m_s, rate_hz, start_chainage_m, curvature_1_m : run settings ([run]).
    sigma_acc_m_s2, sigma_gyro_rad_s : sensor noise standard deviations ([sensors]).
    sense_gravity : the accelerometers sense g times their roll, as real ones do ([sensors]
        ``accelerometers_sense_gravity``; False, the paper's virtual sensors, when the key is absent).
    wheelset_sensor_m, frame_sensor_m : sensor positions (x, y, z) from the car body centre, m.
    t_s, s_m, speed_arr_m_s, wheelset_ay_m_s2, wheelset_wz_rad_s, frame_ay_m_s2 : sensors.csv; read
        from a file, ``t_s`` counts from the first sample, uniform at the file's mean interval (the
        jitter of a logger's time stamps removed; ``read_recording``).
    """

    nominal: dict
    vehicle_extra: dict
    speed_m_s: float
    rate_hz: float
    start_chainage_m: float
    curvature_1_m: float
    sigma_acc_m_s2: float
    sigma_gyro_rad_s: float
    wheelset_sensor_m: tuple
    frame_sensor_m: tuple
    t_s: np.ndarray
    s_m: np.ndarray
    speed_arr_m_s: np.ndarray
    wheelset_ay_m_s2: np.ndarray
    wheelset_wz_rad_s: np.ndarray
    frame_ay_m_s2: np.ndarray
    sense_gravity: bool = False
    #: the vehicle's name ([vehicle] ``name``; ``simulate`` writes it), or None
    vehicle_name: str | None = None
    #: the row of sensors.csv each sample was read from (None: not read from a file)
    rows: np.ndarray | None = None
    #: what the reader found inconsistent but not needed by the filter (``process`` warns)
    notes: tuple[str, ...] = ()


def recording_from_run(run, params, start_chainage_m: float = 0.0, vehicle_name: str | None = None) -> InserviceRecording:
    """The recording of a simulated run (``trolley.inservice.vehicle.RunResult``) and its parameters
    (``vehicle_name``: the name of its vehicle file, or the built-in vehicle's)."""
    from trolley.inservice.bogie import nominal_from_vehicle

    nom = params.nominal()
    pos = params.sensor_positions()
    bogie = nominal_from_vehicle(params)
    return InserviceRecording(
        nominal=nom,
        vehicle_extra={"half_wheelbase_m": params.a_wheelset, "half_bogie_spacing_m": params.a_bogie,
                       "m_frame_kg": params.m_frame, "m_body_kg": params.m_body,
                       **{k: bogie[v] for k, v in BOGIE_KEYS.items()}},
        speed_m_s=float(run.speed_m_s[0]), rate_hz=run.rate_hz, start_chainage_m=float(start_chainage_m),
        curvature_1_m=run.curvature_1_m, sigma_acc_m_s2=run.sigma_acc_m_s2, sigma_gyro_rad_s=run.sigma_gyro_rad_s,
        wheelset_sensor_m=tuple(pos["wheelset_accelerometer"]), frame_sensor_m=tuple(pos["frame_accelerometer"]),
        t_s=run.t_s, s_m=run.s_m + start_chainage_m, speed_arr_m_s=run.speed_m_s,
        wheelset_ay_m_s2=run.wheelset_ay_m_s2, wheelset_wz_rad_s=run.wheelset_wz_rad_s,
        frame_ay_m_s2=run.frame_ay_m_s2, sense_gravity=bool(params.sensor_gravity), vehicle_name=vehicle_name)


def _f(x) -> str:
    return repr(float(x))


def inservice_toml_text(rec: InserviceRecording) -> str:
    """The ``inservice.toml`` text of a recording (FRD signs for the curvature)."""
    inv = {v: k for k, v in VEHICLE_KEYS.items()}
    lines = [f'format = "{FORMAT}"', "", "# nominal parameters of the vehicle (SI); see docs/inservice.md", "[vehicle]"]
    if rec.vehicle_name is not None:
        lines += ["name = " + json.dumps(rec.vehicle_name, ensure_ascii=False)]
    lines += [f"{inv[k]} = {_f(rec.nominal[k])}" for k in VEHICLE_KEYS.values()]
    lines += [f"{k} = {_f(rec.vehicle_extra[k])}" for k in VEHICLE_EXTRA_KEYS]
    if all(k in rec.vehicle_extra for k in BOGIE_KEYS):
        lines += ["# the bogie design model's further parameters (totals per bogie)"]
        lines += [f"{k} = {_f(rec.vehicle_extra[k])}" for k in BOGIE_KEYS]
    lines += ["", "[run]", f"speed_m_s = {_f(rec.speed_m_s)}", f"rate_hz = {_f(rec.rate_hz)}",
              f"start_chainage_m = {_f(rec.start_chainage_m)}",
              "# design curvature, constant; positive for a RIGHT turn", f"curvature_1_m = {_f(-rec.curvature_1_m)}",
              "", "[sensors]", f"sigma_acc_m_s2 = {_f(rec.sigma_acc_m_s2)}",
              f"sigma_gyro_rad_s = {_f(rec.sigma_gyro_rad_s)}",
              "# true for real accelerometers (they sense g x their roll); false: the paper's virtual ones",
              f"accelerometers_sense_gravity = {'true' if rec.sense_gravity else 'false'}",
              "# positions from the car body centre: x forward, y LEFT, z above the rail top, m",
              "wheelset_sensor_m = [" + ", ".join(_f(v) for v in rec.wheelset_sensor_m) + "]",
              "frame_sensor_m = [" + ", ".join(_f(v) for v in rec.frame_sensor_m) + "]"]
    return "\n".join(lines) + "\n"


def write_recording(folder: str | os.PathLike, rec: InserviceRecording) -> None:
    """Write ``folder/inservice.toml`` and ``folder/sensors.csv`` (the folder is created)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    df = pd.DataFrame({"t_s": rec.t_s, "s_m": rec.s_m, "speed_m_s": rec.speed_arr_m_s,
                       "wheelset_ay_m_s2": -np.asarray(rec.wheelset_ay_m_s2),
                       "wheelset_wz_rad_s": -np.asarray(rec.wheelset_wz_rad_s),
                       "frame_ay_m_s2": -np.asarray(rec.frame_ay_m_s2)})
    write_csv_frame(folder / "sensors.csv", df[SENSOR_COLUMNS], "%.9g")
    write_text_atomic(folder / "inservice.toml", inservice_toml_text(rec))


#: plausible sensor position from the car body centre, m (|x| along, |y| across, |z| height): a
#: position typed in millimetres is thousands of metres
SENSOR_POSITION_LIMIT_M = (20.0, 2.0, 5.0)
#: how far [run] start_chainage_m may lie from sensors.csv's first s_m, m (a rounded start)
START_CHAINAGE_TOLERANCE_M = 1.0


def _run_against_columns(speed: float, start: float, start_given: bool, cols: dict, fname: str) -> tuple[str, ...]:
    """Notes on [run] speed_m_s and start_chainage_m that do not describe sensors.csv's run (72
    for 20 m/s is km/h, 5000 against an s_m from 0 another chainage): the filter reads the columns,
    so nothing is refused, but one of the two is wrong and the user must hear which was used."""
    v, s = cols["speed_m_s"], cols["s_m"]
    low, high = float(np.min(v)), float(np.max(v))
    notes = []
    if not low * (1.0 - SAMPLING_TOLERANCE) <= speed <= high * (1.0 + SAMPLING_TOLERANCE):
        notes.append(f"{fname}: run.speed_m_s = {speed:g}, but sensors.csv's speed_m_s runs {low:g}-{high:g} m/s "
                     "(km/h?); the speed column is used")
    if start_given and abs(float(s[0]) - start) > START_CHAINAGE_TOLERANCE_M:
        notes.append(f"{fname}: run.start_chainage_m = {start:g}, but sensors.csv's s_m starts at {float(s[0]):g} m "
                     f"(row {cols['_line'][0]}); the s_m column is used")
    return tuple(notes)


def _implausible_position(key: str, a: tuple, fname: str) -> str | None:
    """A note on a sensor position beyond :data:`SENSOR_POSITION_LIMIT_M` (typed in mm?); the
    filter's model has its own sensor positions, so nothing is refused."""
    far = np.abs(np.asarray(a)) > np.asarray(SENSOR_POSITION_LIMIT_M)
    if not far.any():
        return None
    j = int(np.argmax(far))
    return (f"{fname}: sensors.{key}: {'xyz'[j]} = {a[j]:g} m is beyond {SENSOR_POSITION_LIMIT_M[j]:g} m from the car "
            "body centre (millimetres?)")


def _position(table: dict, key: str, fname: str) -> tuple:
    v = table.get(key)
    if v is None:
        raise InserviceFormatError(f"{fname}: missing key sensors.{key}")
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise InserviceFormatError(f"{fname}: sensors.{key} must be 3 numbers [x, y, z], got {v!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InserviceFormatError(f"{fname}: sensors.{key} must be 3 finite numbers [x, y, z], got {v!r}")
    return tuple(float(x) for x in a)


def parse_toml(path: Path, fmt: str = FORMAT, tables=("vehicle", "run", "sensors"),
               error: type[ValueError] = InserviceFormatError) -> dict:
    """Read a TOML file with a ``format`` key and required tables; ``error`` names the file."""
    fname = path.name
    if not path.is_file():
        raise error(f"{fname}: file not found in {path.parent}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{fname}: not valid TOML ({exc})") from None
    if data.get("format") != fmt:
        raise error(f"{fname}: format must be \"{fmt}\", got {data.get('format')!r}")
    for t in tables:
        if not isinstance(data.get(t), dict):
            raise error(f"{fname}: missing table [{t}]")
    return data


RUN_KEYS = frozenset({"speed_m_s", "rate_hz", "start_chainage_m", "curvature_1_m"})
SENSORS_KEYS = frozenset({"sigma_acc_m_s2", "sigma_gyro_rad_s", "accelerometers_sense_gravity", "wheelset_sensor_m",
                          "frame_sensor_m"})
#: slowest speed a sample may have, m/s: the design model's creep damping goes with 1/V, and at a
#: walking pace (starting, stopping) it is not the in-service model any more
MIN_SPEED_M_S = 1.0
#: how far the samples' rate may lie from [run] rate_hz, and the chainage's rate from the speed
#: column, relative (a time in ms, a speed in km/h or mm/s are far off)
SAMPLING_TOLERANCE = 0.02


#: how far one step between sample times may lie from the recording's usual step, and one sample's
#: time from the uniform grid, in steps: a logger's time stamps jitter (taken by software, rounded
#: to the millisecond, epoch seconds in a float) while a dropped sample is a step of 2 and a gap more
STEP_JITTER = 0.5


def _check_sampling(cols: dict, rate_hz: float, fname: str) -> np.ndarray:
    """Uniform sample times at [run] rate_hz, speeds the model holds for, a chainage that advances
    at the speed column's rate; each refusal names the row (sensors.csv) or the key. Returns the
    sample times as the filter takes them: from the first sample's, k times the mean interval (the
    time stamps' jitter of up to :data:`STEP_JITTER` steps removed)."""
    t, s, v, line = cols["t_s"], cols["s_m"], cols["speed_m_s"], cols["_line"]
    slow = v < MIN_SPEED_M_S
    if np.any(slow):
        i = int(np.argmax(slow))
        raise InserviceFormatError(f"sensors.csv: row {line[i]}, column speed_m_s: {v[i]:g} m/s is below "
                                   f"{MIN_SPEED_M_S:g} m/s, where the in-service model does not hold (starting or "
                                   "stopping): leave those rows out")
    if t.size < 3:
        return t - t[0]
    dt = np.diff(t)
    step = float(np.median(dt))
    off = np.abs(dt - step) > STEP_JITTER * step
    if np.any(off):
        i = int(np.argmax(off))
        raise InserviceFormatError(f"sensors.csv: row {line[i + 1]}, column t_s: a step of {dt[i]:.6g} s after "
                                   f"{t[i]:.6g} s where the samples are {step:.6g} s apart: sample times must be "
                                   "uniform (a gap or a dropped sample?)")
    # the mean interval, a straight line through all time stamps: their rounding and jitter average out
    k = np.arange(t.size)
    kc, tc = k - 0.5 * (t.size - 1), t - t[0]
    step = float(np.dot(kc, tc - tc.mean()) / np.dot(kc, kc))
    drift = np.abs(tc - tc.mean() - kc * step) > STEP_JITTER * step
    if np.any(drift):
        i = int(np.argmax(drift))
        raise InserviceFormatError(f"sensors.csv: row {line[i]}, column t_s: {t[i]:.6g} s is more than half a "
                                   f"sample from the uniform rate of the whole file ({1.0 / step:.6g} Hz): sample "
                                   "times must be uniform (a rate that changes?)")
    if abs(step * rate_hz - 1.0) > SAMPLING_TOLERANCE:
        raise InserviceFormatError(f"{fname}: run.rate_hz = {rate_hz:g}, but the samples of sensors.csv are "
                                   f"{step:.6g} s apart ({1.0 / step:.6g} Hz): column t_s in seconds?")
    # before the rate of the chainage: a train running down the line, an odometer that drops out
    # or is reset were told "speed in m/s, chainage in m?"
    ds = np.diff(s)
    if np.any(ds <= 0):
        i = int(np.argmax(ds <= 0))
        if np.median(ds) < 0:
            why = ("decreases along the run (against the chainage direction?): s_m must increase in the direction of "
                   "travel")
        elif ds[i] == 0:
            why = (f"does not advance at a speed of {v[i + 1]:g} m/s (an odometer that dropped out, or one coarser "
                   "than the run of a sample?)")
        else:
            why = f"goes back by {-ds[i]:.6g} m (an odometer reset?)"
        raise InserviceFormatError(f"sensors.csv: row {line[i + 1]}, column s_m: the chainage {why}")
    ratio = float(np.median(ds / step) / np.median(v))
    if abs(ratio - 1.0) > SAMPLING_TOLERANCE:
        raise InserviceFormatError(f"sensors.csv: column speed_m_s: the chainage s_m advances at {ratio:.6g} times "
                                   "the speed column's value: speed in m/s, chainage in m?")
    return k * step


def read_recording(folder: str | os.PathLike) -> InserviceRecording:
    """Read a recording folder; returns internal signs (module docstring).

    Raises
    ------
    InserviceFormatError
        Missing folder/file/key/column, non-numeric or non-finite value (naming file, row, column),
        time not increasing, speed or rate not positive.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InserviceFormatError(f"{folder}: not a folder")
    toml_path = folder / "inservice.toml"
    data = parse_toml(toml_path)
    fname = toml_path.name
    veh, run, sen = data["vehicle"], data["run"], data["sensors"]
    refuse_unknown(data, {"format", "vehicle", "run", "sensors"}, "", fname, InserviceFormatError)
    refuse_unknown(veh, {*VEHICLE_KEYS, *VEHICLE_EXTRA_KEYS, *BOGIE_KEYS, "name"}, "vehicle", fname, InserviceFormatError)
    refuse_unknown(run, RUN_KEYS, "run", fname, InserviceFormatError)
    refuse_unknown(sen, SENSORS_KEYS, "sensors", fname, InserviceFormatError)
    name = veh.get("name")
    if name is not None and (not isinstance(name, str) or not name.strip()):
        raise InserviceFormatError(f"{fname}: vehicle.name must be a text, got {name!r}")
    try:
        nominal = {v: _num(veh, k, "vehicle", fname) for k, v in VEHICLE_KEYS.items()}
        extra = {k: _num(veh, k, "vehicle", fname) for k in VEHICLE_EXTRA_KEYS}
        if any(k in veh for k in BOGIE_KEYS):
            extra.update({k: _num(veh, k, "vehicle", fname) for k in BOGIE_KEYS})
        speed = _num(run, "speed_m_s", "run", fname)
        rate = _num(run, "rate_hz", "run", fname)
        start = _num(run, "start_chainage_m", "run", fname, default=0.0, required=False)
        curv = _num(run, "curvature_1_m", "run", fname, default=0.0, required=False)
        sa = _num(sen, "sigma_acc_m_s2", "sensors", fname)
        sg = _num(sen, "sigma_gyro_rad_s", "sensors", fname)
        gravity = sen.get("accelerometers_sense_gravity", False)
        if not isinstance(gravity, bool):
            raise InserviceFormatError(f"{fname}: sensors.accelerometers_sense_gravity must be true or false, "
                                       f"got {gravity!r}")
        cols = _read_csv(folder / "sensors.csv", SENSOR_COLUMNS, monotonic="t_s", strict=True)
    except TgmsFormatError as exc:
        raise InserviceFormatError(str(exc)) from None
    for key, val in (("run.speed_m_s", speed), ("run.rate_hz", rate)):
        if val <= 0:
            raise InserviceFormatError(f"{fname}: {key} must be > 0, got {val}")
    # (the values were read as finite numbers above)
    for key in (k for k in (*VEHICLE_KEYS, *VEHICLE_EXTRA_KEYS, *BOGIE_KEYS) if k in veh):
        val = float(veh[key])
        if val < 0 or (val == 0 and key not in MAY_BE_ZERO):
            raise InserviceFormatError(f"{fname}: vehicle.{key} must be {'>= 0' if key in MAY_BE_ZERO else '> 0'}, "
                                       f"got {val}")
    if abs(curv) > MAX_CURVATURE_1_M:
        raise InserviceFormatError(f"{fname}: run.curvature_1_m must be within +-{MAX_CURVATURE_1_M:g} 1/m (radius "
                                   f"{1 / MAX_CURVATURE_1_M:g} m or more), got {curv:g}: a radius typed for 1/R?")
    for key, val in (("sensors.sigma_acc_m_s2", sa), ("sensors.sigma_gyro_rad_s", sg)):
        if val < 0:
            raise InserviceFormatError(f"{fname}: {key} must be >= 0, got {val}")
    if np.any(cols["speed_m_s"] < 0):
        # (0, a train standing in a station, is said with the slow rows below)
        i = int(np.argmax(cols["speed_m_s"] < 0))
        raise InserviceFormatError(f"sensors.csv: row {cols['_line'][i]}, column speed_m_s: must be > 0")
    cols["t_s"] = _check_sampling(cols, rate, fname)
    notes = _run_against_columns(speed, start, "start_chainage_m" in run, cols, fname)
    positions = {k: _position(sen, k, fname) for k in ("wheelset_sensor_m", "frame_sensor_m")}
    notes += tuple(n for n in (_implausible_position(k, v, fname) for k, v in positions.items()) if n)
    return InserviceRecording(
        nominal=nominal, vehicle_extra=extra, speed_m_s=speed, rate_hz=rate, start_chainage_m=start,
        curvature_1_m=-curv, sigma_acc_m_s2=sa, sigma_gyro_rad_s=sg,
        wheelset_sensor_m=positions["wheelset_sensor_m"], frame_sensor_m=positions["frame_sensor_m"],
        t_s=cols["t_s"], s_m=cols["s_m"], speed_arr_m_s=cols["speed_m_s"],
        wheelset_ay_m_s2=-cols["wheelset_ay_m_s2"], wheelset_wz_rad_s=-cols["wheelset_wz_rad_s"],
        frame_ay_m_s2=-cols["frame_ay_m_s2"], sense_gravity=gravity,
        vehicle_name=name.strip() if isinstance(name, str) else None, rows=np.asarray(cols["_line"]), notes=notes)


def bogie_nominal(rec: InserviceRecording) -> dict | None:
    """Nominal parameters of the bogie design model (trolley.inservice.bogie.BogieParameters) from a
    recording's [vehicle] table, or None when it lacks the keys of :data:`BOGIE_KEYS`."""
    x = rec.vehicle_extra
    if not all(k in x for k in BOGIE_KEYS):
        return None
    n = rec.nominal
    out = {k: n[k] for k in ("m", "I", "l", "ls", "conicity", "r0", "f11", "f22", "kx", "cx", "ky", "cy")}
    out.update(a=x["half_wheelbase_m"], mf=x["m_frame_kg"], mb=x["m_body_kg"] / 2.0)
    out.update({v: x[k] for k, v in BOGIE_KEYS.items()})
    return out


#: design-model parameters that calibration identifies (Munoz 2021 Eq. 6): they differ from the
#: recording's nominal values by design
IDENTIFIED = frozenset({"kx", "cx", "ky", "cy"})


def vehicle_differences(rec: InserviceRecording, params, rel_tol: float = 1e-6) -> dict:
    """The recording's [vehicle] values that differ from a calibrated design model's.

    A model is calibrated for one vehicle (``trolley inservice calibrate --vehicle``); a recording
    from another one (other masses, wheel radius, conicity, creep coefficients...) needs its own
    calibration, and neither its estimate nor its sigmas say so. The identified suspension values
    (:data:`IDENTIFIED`) are not compared; nor are the bogie keys a recording does not have.

    Parameters
    ----------
    rec : the recording.
    params : the model's ModelParameters (kind "paper") or BogieParameters (kind "bogie").
    rel_tol : relative tolerance (a value typed with six or more significant digits matches).

    Returns
    -------
    {[vehicle] key: (recording's value, model's value)} in the file's units, empty when they agree.
    """
    pairs = {k: (rec.nominal[v], v) for k, v in VEHICLE_KEYS.items() if v not in IDENTIFIED}
    if params.KIND == "bogie":
        # the bogie model holds the frame and half the body, not the paper's supported mass
        pairs = {k: pv for k, pv in pairs.items() if hasattr(params, pv[1]) and pv[1] != "mf"}
        x = rec.vehicle_extra
        pairs.update({"half_wheelbase_m": (x["half_wheelbase_m"], "a"), "m_frame_kg": (x["m_frame_kg"], "mf"),
                      "m_body_kg": (x["m_body_kg"], "mb")})
        pairs.update({k: (x[k], v) for k, v in BOGIE_KEYS.items() if k in x})
    out = {}
    for key, (value, name) in pairs.items():
        model = float(getattr(params, name)) * (2.0 if key == "m_body_kg" else 1.0)
        if not np.isclose(value, model, rtol=rel_tol, atol=0.0):
            out[key] = (float(value), model)
    return out


def write_truth(path: str | os.PathLike, s_m, alignment_m, vertical_m, curvature_1_m) -> None:
    """Write truth.csv from internal signs (alignment left +, curvature left +) as FRD (right +)."""
    s = np.asarray(s_m, float)
    df = pd.DataFrame({"s_m": s, "alignment_m": -np.asarray(alignment_m, float),
                       "vertical_m": np.asarray(vertical_m, float),
                       "curvature_1_m": -np.broadcast_to(np.asarray(curvature_1_m, float), s.shape)})
    write_csv_frame(Path(path), df[TRUTH_COLUMNS], "%.9g")


def read_truth(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read truth.csv; returns internal signs (alignment and curvature positive to the LEFT)."""
    path = Path(path)
    try:
        cols = _read_csv(path, TRUTH_COLUMNS, monotonic="s_m", strict=True)
    except TgmsFormatError as exc:
        raise InserviceFormatError(str(exc).replace("time goes backwards", "chainage not increasing")) from None
    cols["alignment_m"] = -cols["alignment_m"]
    cols["curvature_1_m"] = -cols["curvature_1_m"]
    return cols
