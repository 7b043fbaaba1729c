"""The vehicle file of ``trolley inservice simulate | calibrate --vehicle`` (docs/inservice.md, "Your vehicle").

Munoz 2021 identifies its simplified model against a complete multibody model of the vehicle
that carries the sensors (Sec. III-B, III-D, Eq. 6). Here the truth simulator
(``trolley.inservice.vehicle``) plays that role, and this file describes the vehicle to it: the
fields of :class:`trolley.inservice.vehicle.VehicleParameters` under names that carry their units,
and optionally the sensors' white-noise sigmas. A key left out keeps the Manchester benchmark
vehicle's value (the simulator's default); an unknown key (a typo) is refused with the nearest
known one, so a partial file never silently means the default. SI units, heights above the rail
top, primary values per axle box, secondary values per side.

    format = "trolley-inservice-vehicle/1"
    name = "my EMU, trailer car"          # optional
    [vehicle]
    m_body_kg = 32000.0
    ...
    [sensors]                             # optional
    sigma_acc_m_s2 = 0.01
    sigma_gyro_rad_s = 0.0005
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from survey.atomicwrite import write_text_atomic
from survey.inservice_io import parse_toml
from survey.limits import refuse_unknown
from survey.tgms_io import TgmsFormatError, _num

FORMAT = "trolley-inservice-vehicle/1"

#: file key -> VehicleParameters field (the robustness factors and sensor_gravity are run
#: conditions, given on the command line, not properties of the vehicle)
KEYS = {
    "m_body_kg": "m_body", "ixx_body_kg_m2": "ixx_body", "iyy_body_kg_m2": "iyy_body",
    "izz_body_kg_m2": "izz_body", "h_body_m": "h_body",
    "m_frame_kg": "m_frame", "ixx_frame_kg_m2": "ixx_frame", "iyy_frame_kg_m2": "iyy_frame",
    "izz_frame_kg_m2": "izz_frame", "h_frame_m": "h_frame",
    "m_wheelset_kg": "m_wheelset", "ixx_wheelset_kg_m2": "ixx_wheelset", "izz_wheelset_kg_m2": "izz_wheelset",
    "r0_m": "r0", "half_contact_spacing_m": "b", "half_wheelbase_m": "a_wheelset",
    "half_bogie_spacing_m": "a_bogie",
    "kx_primary_n_m": "kx_p", "ky_primary_n_m": "ky_p", "kz_primary_n_m": "kz_p",
    "cx_primary_n_s_m": "cx_p", "cy_primary_n_s_m": "cy_p", "cz_primary_n_s_m": "cz_p",
    "half_primary_spacing_m": "d_p",
    "kx_secondary_per_side_n_m": "kx_s", "ky_secondary_per_side_n_m": "ky_s",
    "kz_secondary_per_side_n_m": "kz_s", "cx_secondary_per_side_n_s_m": "cx_s",
    "cy_secondary_per_side_n_s_m": "cy_s", "cz_secondary_per_side_n_s_m": "cz_s",
    "half_secondary_spacing_m": "d_s", "h_secondary_m": "h_s", "k_antiroll_n_m_rad": "k_antiroll",
    "conicity": "conicity", "conicity_growth_m": "conicity_growth_m", "f11_n": "f11", "f22_n": "f22",
    "friction_coefficient": "mu", "flange_clearance_m": "flange_clearance_m",
    "flange_stiffness_n_m": "flange_stiffness_n_m",
}
#: keys that may be 0 (springs and dampers that a vehicle may lack); every other value must be > 0
#: (the vertical springs carry the weight, so kz_primary and kz_secondary may not be 0)
MAY_BE_ZERO = frozenset({"kx_primary_n_m", "ky_primary_n_m", "cx_primary_n_s_m", "cy_primary_n_s_m",
                         "cz_primary_n_s_m", "kx_secondary_per_side_n_m", "ky_secondary_per_side_n_m",
                         "cx_secondary_per_side_n_s_m", "cy_secondary_per_side_n_s_m",
                         "cz_secondary_per_side_n_s_m", "k_antiroll_n_m_rad"})
SENSOR_KEYS = ("sigma_acc_m_s2", "sigma_gyro_rad_s")
#: the range of each key, from light rail to heavy freight (SI): a value outside is a typo or a
#: wrong unit (mm typed for m made a run need 24 GB; a 1e200 noise an estimate of 1e203 mm)
RANGES = {
    "m_body_kg": (1e3, 2e5), "ixx_body_kg_m2": (1e3, 1e7), "iyy_body_kg_m2": (1e4, 1e8),
    "izz_body_kg_m2": (1e4, 1e8), "h_body_m": (0.5, 5.0),
    "m_frame_kg": (100.0, 2e4), "ixx_frame_kg_m2": (50.0, 5e4), "iyy_frame_kg_m2": (50.0, 5e4),
    "izz_frame_kg_m2": (50.0, 5e4), "h_frame_m": (0.2, 2.0),
    "m_wheelset_kg": (200.0, 5e3), "ixx_wheelset_kg_m2": (50.0, 5e3), "izz_wheelset_kg_m2": (50.0, 5e3),
    "r0_m": (0.2, 0.8), "half_contact_spacing_m": (0.45, 0.9), "half_wheelbase_m": (0.5, 3.0),
    "half_bogie_spacing_m": (2.0, 15.0),
    "kx_primary_n_m": (0.0, 1e9), "ky_primary_n_m": (0.0, 1e9), "kz_primary_n_m": (1e4, 1e8),
    "cx_primary_n_s_m": (0.0, 1e7), "cy_primary_n_s_m": (0.0, 1e7), "cz_primary_n_s_m": (0.0, 1e7),
    "half_primary_spacing_m": (0.3, 1.5),
    "kx_secondary_per_side_n_m": (0.0, 1e8), "ky_secondary_per_side_n_m": (0.0, 1e8),
    "kz_secondary_per_side_n_m": (1e4, 1e8), "cx_secondary_per_side_n_s_m": (0.0, 1e7),
    "cy_secondary_per_side_n_s_m": (0.0, 1e7), "cz_secondary_per_side_n_s_m": (0.0, 1e7),
    "half_secondary_spacing_m": (0.3, 1.5), "h_secondary_m": (0.2, 3.0), "k_antiroll_n_m_rad": (0.0, 1e8),
    "conicity": (0.01, 1.0), "conicity_growth_m": (1e-3, 0.05), "f11_n": (1e5, 1e9), "f22_n": (1e5, 1e9),
    "friction_coefficient": (0.01, 1.0), "flange_clearance_m": (1e-3, 0.03), "flange_stiffness_n_m": (1e5, 1e9),
    "sigma_acc_m_s2": (0.0, 10.0), "sigma_gyro_rad_s": (0.0, 1.0),
}


class VehicleFileError(ValueError):
    """A vehicle file that does not follow docs/inservice.md ("Your vehicle")."""


@dataclass(frozen=True)
class VehicleFile:
    """A vehicle file read.

    Attributes
    ----------
    params : the truth simulator's vehicle (run conditions at their defaults).
    name : the file's ``name`` or its file name.
    defaults : file keys the file left out (they keep the Manchester benchmark vehicle's values).
    sigma_acc_m_s2, sigma_gyro_rad_s : the sensors' white-noise sigmas per sample.
    """

    params: object
    name: str
    defaults: tuple
    sigma_acc_m_s2: float
    sigma_gyro_rad_s: float


def _finite(table: dict, key: str, where: str, fname: str) -> float:
    """The recording reader's number check (survey.tgms_io._num), as this file's error."""
    try:
        return _num(table, key, where, fname)
    except TgmsFormatError as exc:
        raise VehicleFileError(str(exc)) from None


#: the hint of an unknown key without a near one
_KNOWN_KEYS = " (known keys: docs/inservice.md, \"Your vehicle\")"


def _check_range(key: str, value: float, where: str, fname: str) -> None:
    lo, hi = RANGES[key]
    if not lo <= value <= hi:
        unit = ("metres, not millimetres?" if key.endswith("_m") else "kilograms, not tonnes?" if key.endswith("_kg")
                else "SI units")
        raise VehicleFileError(f"{fname}: {where}.{key} = {value:g} is outside {lo:g}..{hi:g}, the range of rail "
                               f"vehicles ({unit})")


#: what writes a vehicle file, for the messages about a folder given instead of one
VEHICLE_MADE_BY = "`trolley inservice vehicle --out FILE` writes one"


def read_vehicle(path: str | os.PathLike) -> VehicleFile:
    """Read a vehicle file (raises :class:`VehicleFileError` naming the file and the key).

    Besides each value's sign, the geometry must hold together: the bogies may not overlap
    (half_bogie_spacing_m > half_wheelbase_m) and the car body's centre of gravity must be above
    the frame's; the vehicle must also build (VehicleParameters' own checks).
    """
    from trolley.inservice.vehicle import SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S, VehicleParameters

    path = Path(path)
    fname = path.name
    if path.is_dir():
        raise VehicleFileError(f"{path}: is a folder, not a vehicle file ({VEHICLE_MADE_BY})")
    data = parse_toml(path, FORMAT, ("vehicle",), VehicleFileError)
    for key in data:
        if key not in ("format", "name", "vehicle", "sensors"):
            raise VehicleFileError(f"{fname}: unknown key or table {key!r} (the file has format, name, "
                                   "[vehicle] and [sensors])")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise VehicleFileError(f"{fname}: name must be a text, got {name!r}")
    veh = data["vehicle"]
    refuse_unknown(veh, KEYS, "vehicle", fname, VehicleFileError, qualify=False, otherwise=_KNOWN_KEYS)
    values = {}
    for key, val in ((k, _finite(veh, k, "vehicle", fname)) for k in veh):
        if val < 0 or (val == 0 and key not in MAY_BE_ZERO):
            raise VehicleFileError(f"{fname}: vehicle.{key} must be {'>= 0' if key in MAY_BE_ZERO else '> 0'}, "
                                   f"got {val:g}")
        _check_range(key, val, "vehicle", fname)
        values[KEYS[key]] = val
    sen = data.get("sensors", {})
    if not isinstance(sen, dict):
        raise VehicleFileError(f"{fname}: sensors must be a table [sensors]")
    refuse_unknown(sen, SENSOR_KEYS, "sensors", fname, VehicleFileError, qualify=False, otherwise=_KNOWN_KEYS)
    sigmas = {k: (_finite(sen, k, "sensors", fname) if k in sen else d)
              for k, d in zip(SENSOR_KEYS, (SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S))}
    for k, v in sigmas.items():
        if v < 0:
            raise VehicleFileError(f"{fname}: sensors.{k} must be >= 0, got {v:g}")
        _check_range(k, v, "sensors", fname)
    try:
        params = VehicleParameters(**values)
    except ValueError as exc:
        raise VehicleFileError(f"{fname}: {exc}") from None
    inv = {v: k for k, v in KEYS.items()}
    if params.a_bogie <= params.a_wheelset:
        raise VehicleFileError(f"{fname}: vehicle.{inv['a_bogie']} ({params.a_bogie:g} m) must exceed "
                               f"vehicle.{inv['a_wheelset']} ({params.a_wheelset:g} m): the bogies would overlap")
    if params.h_body <= params.h_frame:
        raise VehicleFileError(f"{fname}: vehicle.{inv['h_body']} ({params.h_body:g} m) must exceed "
                               f"vehicle.{inv['h_frame']} ({params.h_frame:g} m): heights are above the rail top")
    return VehicleFile(params=params, name=name.strip(), defaults=tuple(k for k in KEYS if k not in veh),
                       sigma_acc_m_s2=sigmas["sigma_acc_m_s2"], sigma_gyro_rad_s=sigmas["sigma_gyro_rad_s"])


def vehicle_toml_text(params, name: str, sigma_acc_m_s2: float, sigma_gyro_rad_s: float) -> str:
    """The vehicle file of ``params`` (a VehicleParameters), every key written."""
    lines = [f'format = "{FORMAT}"', f"name = {json.dumps(name, ensure_ascii=False)}", "",
             "# the truth simulator's vehicle (SI; heights above the rail top; primary values per axle box,",
             "# secondary per side); docs/inservice.md, \"Your vehicle\"", "[vehicle]"]
    lines += [f"{key} = {float(getattr(params, field))!r}" for key, field in KEYS.items()]
    lines += ["", "# white noise of the sensors per sample", "[sensors]",
              f"sigma_acc_m_s2 = {float(sigma_acc_m_s2)!r}", f"sigma_gyro_rad_s = {float(sigma_gyro_rad_s)!r}"]
    return "\n".join(lines) + "\n"


def write_vehicle(path: str | os.PathLike, params, name: str, sigma_acc_m_s2: float, sigma_gyro_rad_s: float) -> None:
    """Write a vehicle file atomically."""
    write_text_atomic(Path(path), vehicle_toml_text(params, name, sigma_acc_m_s2, sigma_gyro_rad_s))

