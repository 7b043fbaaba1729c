"""The calibrated estimator model file of ``trolley inservice`` (model.toml; docs/inservice.md).

Holds a :class:`trolley.inservice.identification.EstimatorModel`: the design model's kind
(``kind = "bogie"``, trolley.inservice.bogie, or ``"paper"``, the simplified model of Munoz 2021;
files without the key are "paper") and its parameters (Munoz 2021 Eq. 4, with p_opt identified by
Eq. 6; ``sensor_gravity`` a boolean, false when absent), the diagonals of Q (per step of ``dt_s``) and R (Eq. 26-29, tuned), the sigma scale, the
calibration runs' rms normalized innovations (the reference of the consistency check; optional),
and with correlated noises the full Q, R and their cross covariance S. SI units throughout.
Written atomically; the reader names the file and the key of any bad value.
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from survey.atomicwrite import write_text_atomic
from survey.inservice_io import parse_toml
from survey.limits import refuse_unknown

FORMAT = "trolley-inservice-model/1"
#: sample intervals a model file may hold, s (filter rates 5 Hz to 100 kHz)
MIN_DT_S, MAX_DT_S = 1e-5, 0.2


#: the correlated noises' full matrices: all or none
FULL_MATRIX_KEYS = ("q_matrix", "r_matrix", "s_matrix")
#: the keys of [noise] (speed_m_s, innovation_rms and the full matrices are optional)
NOISE_KEYS = frozenset({"dt_s", "q_diagonal", "r_diagonal", "sigma_scale", "q_dynamics_factor", "q_xi_factor",
                        "sigma_xi_virtual_m", "speed_m_s", "innovation_rms", *FULL_MATRIX_KEYS})


#: the model ``trolley inservice calibrate`` writes with its defaults (the built-in vehicle, 20 m/s,
#: 200 Hz, 400 m, seeds 1000-1003), shipped so that ``process`` without ``--model`` is calibrated for a
#: recording of that vehicle; tests/test_inservice_builtin_model.py checks that it still is that
BUILTIN_MODEL_PATH = Path(__file__).with_name("inservice_builtin_model.toml")


class ModelFileError(ValueError):
    """A model.toml that does not follow docs/inservice.md."""


def model_toml_text(model, provenance: str | None = None) -> str:
    """TOML text of an EstimatorModel; ``provenance`` (the vehicle and runs it was calibrated on)
    becomes a comment line, for the reader of the file."""
    lines = [f'format = "{FORMAT}"', f'kind = "{model.params.KIND}"']
    if provenance:
        lines += ["# " + " ".join(provenance.split())]
    lines += ["",
             "# design model parameters (Munoz 2021 Eq. 4; the bogie model: trolley.inservice.bogie), SI",
             "[parameters]"]
    lines += [f"{k} = {str(v).lower()}" if isinstance(v, bool) else f"{k} = {float(v)!r}"
              for k, v in asdict(model.params).items()]
    lines += ["", "# filter noise (Munoz 2021 Eq. 26-29, tuned); Q per step of dt_s", "[noise]",
              f"dt_s = {model.dt_s!r}", "q_diagonal = [" + ", ".join(repr(float(v)) for v in np.diag(model.Q)) + "]",
              "r_diagonal = [" + ", ".join(repr(float(v)) for v in np.diag(model.R)) + "]",
              f"sigma_scale = {model.sigma_scale!r}", f"q_dynamics_factor = {model.q_dynamics_factor!r}",
              f"q_xi_factor = {model.q_xi_factor!r}", f"sigma_xi_virtual_m = {model.sigma_xi_virtual_m!r}"]
    if model.speed_m_s is not None:
        lines += ["# speed of the calibration runs, m/s (process compares the recording's with it)",
                  f"speed_m_s = {float(model.speed_m_s)!r}"]
    if model.innovation_rms is not None:
        lines += ["# rms normalized innovations [wheelset acc, gyro, frame acc] on the calibration runs",
                  "# (identification.model_consistency compares recordings with them)",
                  "innovation_rms = [" + ", ".join(repr(float(v)) for v in model.innovation_rms) + "]"]
    if model.S is not None:
        n = len(model.Q)
        lines += [f"# correlated noises (identification.cross_covariance_from_residuals): full Q ({n}x{n}), R (4x4)",
                  f"# and S ({n}x4), row by row"]
        lines += [f"{key} = [" + ", ".join(repr(float(v)) for v in np.ravel(m)) + "]"
                  for key, m in (("q_matrix", model.Q), ("r_matrix", model.R), ("s_matrix", model.S))]
    return "\n".join(lines) + "\n"


def write_model(path: str | os.PathLike, model, provenance: str | None = None) -> None:
    """Write model.toml atomically (``provenance``: see :func:`model_toml_text`)."""
    write_text_atomic(Path(path), model_toml_text(model, provenance))


def _number(table: dict, key: str, where: str, fname: str) -> float:
    if key not in table:
        raise ModelFileError(f"{fname}: missing key {where}.{key}")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ModelFileError(f"{fname}: {where}.{key} must be a finite number, got {v!r}")
    return float(v)


def _flag(table: dict, key: str, where: str, fname: str) -> bool:
    # optional: files written before the key existed are the paper's virtual sensors
    v = table.get(key, False)
    if not isinstance(v, bool):
        raise ModelFileError(f"{fname}: {where}.{key} must be true or false, got {v!r}")
    return v


def _vector(table: dict, key: str, n: int, fname: str, signed: bool = False, hint: str = "") -> np.ndarray:
    """``noise.key`` as ``n`` finite numbers (>= 0 unless ``signed``). The message names what is
    wrong, never the whole list: a q_matrix holds 400 numbers, and a list one number too long
    printed in full hid the one fact that mattered, its length. ``hint`` follows a length
    message (where ``n`` comes from)."""
    want = f"{fname}: noise.{key} must be {n} finite numbers{'' if signed else ' >= 0'}"
    if key not in table:
        raise ModelFileError(f"{fname}: missing key noise.{key}")
    v = table[key]
    if not isinstance(v, list):
        raise ModelFileError(f"{want} in a list [...], got {_short(v)}")
    if len(v) != n:
        raise ModelFileError(f"{want}, got {len(v)}{hint}")
    for i, x in enumerate(v):
        # (bool is an int to Python; a nested list is a matrix written as rows)
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ModelFileError(f"{want}; number {i + 1} is {'a list' if isinstance(x, list) else _short(x)}")
        if not math.isfinite(_float(x)) or (not signed and x < 0):
            raise ModelFileError(f"{want}; number {i + 1} is {_float(x)!r}")
    return np.asarray(v, dtype=float)


def _short(v: object) -> str:
    """``repr(v)``, cut to 40 characters (a long text typed where the numbers belong)."""
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _float(x: int | float) -> float:
    try:
        return float(x)
    except OverflowError:        # an integer beyond a float's range (10**400) is inf to the filter
        return math.inf if x > 0 else -math.inf


def model_provenance(path: str | os.PathLike) -> str | None:
    """The provenance comment of a model file written by :func:`write_model` ("calibrated for ..."),
    or None when the file has none."""
    for line in Path(path).read_text(encoding="utf-8").splitlines()[:4]:
        if line.startswith("# calibrated for "):
            return line[2:]
    return None


def read_model(path: str | os.PathLike):
    """Read model.toml into an EstimatorModel (raises ModelFileError naming file and key)."""
    from trolley.inservice.bogie import BogieParameters
    from trolley.inservice.identification import EstimatorModel
    from trolley.inservice.model import ModelParameters

    path = Path(path)
    fname = path.name
    data = parse_toml(path, FORMAT, ("parameters", "noise"), ModelFileError)
    par, noi = data["parameters"], data["noise"]
    kinds = {c.KIND: c for c in (ModelParameters, BogieParameters)}
    kind = data.get("kind", ModelParameters.KIND)
    if kind not in kinds:
        raise ModelFileError(f"{fname}: kind must be one of {', '.join(sorted(kinds))}, got {kind!r}")
    cls = kinds[kind]
    # a mistyped optional key would read as absent (innovation_rms: no consistency check, "calibrated
    # before the check existed"); older files have fewer keys, never others
    refuse_unknown(data, {"format", "kind", "parameters", "noise"}, "", fname, ModelFileError)
    refuse_unknown(par, {f.name for f in fields(cls)}, "parameters", fname, ModelFileError,
                   otherwise=f" (the {kind} design model has no such parameter: is the file's kind right?)")
    refuse_unknown(noi, NOISE_KEYS, "noise", fname, ModelFileError)
    full = [k for k in FULL_MATRIX_KEYS if k in noi]
    if full and len(full) < len(FULL_MATRIX_KEYS):
        lost = next(k for k in FULL_MATRIX_KEYS if k not in noi)
        raise ModelFileError(f"{fname}: missing key noise.{lost}: {', '.join(FULL_MATRIX_KEYS)} go together (a file "
                             "cut short?); without them the diagonals alone are a worse model")
    try:
        params = cls(**{f.name: (_flag if f.type in (bool, "bool") else _number)(par, f.name, "parameters", fname)
                        for f in fields(cls)})
    except ValueError as exc:
        if isinstance(exc, ModelFileError):
            raise
        raise ModelFileError(f"{fname}: {exc}") from None
    dt = _number(noi, "dt_s", "noise", fname)
    if not MIN_DT_S <= dt <= MAX_DT_S:
        raise ModelFileError(f"{fname}: noise.dt_s must be {MIN_DT_S:g}-{MAX_DT_S:g} s (a filter rate of "
                             f"{1 / MAX_DT_S:g}-{1 / MIN_DT_S:g} Hz), got {dt}")
    n = params.n_state
    # a length message says where the length comes from: a file of the other kind has other lengths
    states = f" (the {kind} design model has {n} states)"
    Q = np.diag(_vector(noi, "q_diagonal", n, fname, hint=states))
    R, S = np.diag(_vector(noi, "r_diagonal", 4, fname)), None
    if full:
        Q = _vector(noi, "q_matrix", n * n, fname, signed=True, hint=f" ({n}x{n} row by row{states})").reshape(n, n)
        R = _vector(noi, "r_matrix", 16, fname, signed=True, hint=" (4x4 row by row)").reshape(4, 4)
        S = _vector(noi, "s_matrix", 4 * n, fname, signed=True, hint=f" ({n}x4 row by row{states})").reshape(n, 4)
    _check_covariances(Q, R, fname)
    nu = None
    if "innovation_rms" in noi:      # (optional: files written before the consistency check lack it)
        nu = _vector(noi, "innovation_rms", 3, fname, signed=True)
        if not np.all(nu > 0):
            raise ModelFileError(f"{fname}: noise.innovation_rms must be 3 numbers > 0, got {noi['innovation_rms']!r}")
    scalars = {k: _number(noi, k, "noise", fname)
               for k in ("sigma_scale", "q_dynamics_factor", "q_xi_factor", "sigma_xi_virtual_m")}
    for k, v in scalars.items():
        if v <= 0:
            raise ModelFileError(f"{fname}: noise.{k} must be > 0, got {v}")
    speed = None
    if "speed_m_s" in noi:     # (optional: files written before the speed check lack it)
        speed = _number(noi, "speed_m_s", "noise", fname)
        if speed <= 0:
            raise ModelFileError(f"{fname}: noise.speed_m_s must be > 0, got {speed}")
    return EstimatorModel(params, Q, R, dt, scalars["sigma_scale"], scalars["q_dynamics_factor"],
                          scalars["q_xi_factor"], scalars["sigma_xi_virtual_m"], S, nu, speed)


def _check_covariances(Q: np.ndarray, R: np.ndarray, fname: str) -> None:
    """Q symmetric and positive semi-definite, R symmetric and positive definite (the filter
    inverts R and its innovation covariance): a hand-edited sign is caught here, not as NaN later."""
    for key, m, strict in (("q", Q, False), ("r", R, True)):
        scale = float(np.abs(m).max()) or 1.0
        if not np.allclose(m, m.T, rtol=0.0, atol=1e-9 * scale):
            raise ModelFileError(f"{fname}: noise.{key}_matrix must be symmetric")
        low = float(np.linalg.eigvalsh(0.5 * (m + m.T)).min())
        if (strict and low <= 0.0) or low < -1e-9 * scale:
            what = "positive definite" if strict else "positive semi-definite"
            raise ModelFileError(f"{fname}: noise.{key}_matrix (or {key}_diagonal) must be {what}; smallest "
                                 f"eigenvalue {low:.3g}")
