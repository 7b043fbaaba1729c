"""``trolley tgms ...``: synthetic TGMS recordings, processing into irregularities, tuning.

* ``trolley tgms simulate --out DIR`` writes a recording folder (FORMATS.md section 3) and truth.csv.
* ``trolley tgms process DIR --out OUT`` writes irregularities.csv and PNG plots; when DIR holds a
  truth.csv (synthetic recording) the accuracy against it is added to the JSON summary.
* ``trolley tgms tune DIR --out params.toml`` estimates the noise parameters by constrained
  maximum likelihood (Gonzalez-Carbajal 2023 Sec. 4.2).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console

from survey import jsonout
from survey.atomicwrite import (OutputError, all_or_nothing, check_outputs, guard_overwrite, write_marker,
                                write_text_atomic, write_with)
from survey.commands.options import (JsonAlways, RailProfile, TgmsBox, TgmsModel, TgmsOrientation, TgmsTrajectory,
                                     old_name, renamed)
from survey.limits import check_allocation, check_file_option, check_finite, check_seed

console = Console(stderr=True)

tgms_app = typer.Typer(help="Track Geometry Measuring System: cameras + lasers + IMU + encoder -> track irregularities.",
                       no_args_is_help=True, rich_markup_mode=None)


def _fail(msg: str) -> None:
    from rich.text import Text

    console.print(Text.assemble(("error:", "red"), " ", msg), highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


def _warn(msg: str) -> None:
    console.print(f"warning: {msg}", highlight=False, markup=False, soft_wrap=True)


def _read_recording(folder: Path):
    """The recording in ``folder``; a bad folder is one line naming the file, exit 2."""
    from survey import tgms_io

    try:
        return tgms_io.read_recording(folder)
    except tgms_io.TgmsFormatError as exc:
        _fail(str(exc))


#: shortest wavelength the output grid holds for --band, in steps (two are its Nyquist limit; the
#: low-pass edge needs a little room above it): the short edge of any band, and the one a single
#: LONG implies (bug hunt: --band D1 at --step-m 5 was accepted, 3-25 m on a 5 m grid)
BAND_MIN_STEPS = 2.5


def parse_band(text: str, step_m: float):
    """``--band``: D1, D2, D3, none, SHORT-LONG (e.g. 3-25) or LONG (a user cut-off: keeps the
    wavelengths from :data:`BAND_MIN_STEPS` steps up to LONG, i.e. removes the longer ones). SHORT
    may not be below that either. Returns (short_m, long_m) or None."""
    from trolley.bands import BANDS
    t = text.strip()
    if t.lower() == "none":
        return None
    shortest = BAND_MIN_STEPS * step_m
    single = "-" not in t and t.upper() not in BANDS
    try:
        if t.upper() in BANDS:
            a, b = BANDS[t.upper()]
        elif single:
            a, b = shortest, float(t)
        else:
            a, b = (float(x) for x in t.split("-", 1))
    except ValueError:
        raise ValueError(f"--band {text!r}: expected D1, D2, D3, none, SHORT-LONG or LONG in metres") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ValueError(f"--band {text!r}: wavelengths must be finite numbers of metres")
    if single and not b > a:
        raise ValueError(f"--band {text!r}: the cut-off LONG must exceed {BAND_MIN_STEPS:g} steps ({a:g} m at "
                         f"--step-m {step_m:g})")
    if not (0 < a < b):
        raise ValueError(f"--band {text!r}: need 0 < SHORT < LONG")
    if a < shortest:
        raise ValueError(f"--band {text!r}: its short edge {a:g} m is below {BAND_MIN_STEPS:g} steps ({shortest:g} m "
                         f"at --step-m {step_m:g}), shorter than the output grid holds; use --step-m "
                         f"{a / BAND_MIN_STEPS:g} or less, or a band from {shortest:g} m up")
    return (a, b)


def band_edge_flags(values, step_m: float, short_m: float, long_m: float):
    """1 where a band-passed cell lies within ``long_m`` of the end of its record (the zero-phase
    filter's edge transient, about one long wavelength), else 0. Records end at the array's ends
    and at NaN gaps longer than ``short_m`` (shorter gaps are bridged by ``trolley.bands``)."""
    import numpy as np
    v = np.asarray(values, float)
    n = len(v)
    bad = ~np.isfinite(v)
    # NaN runs longer than short_m split the record; shorter ones do not
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(np.int8), [0]])))
    starts, ends = edges[::2], edges[1::2]
    split = np.zeros(n, bool)
    for a, b in zip(starts, ends):        # loop over gaps, not samples
        if (b - a) * step_m > short_m:
            split[a:b] = True
    idx = np.arange(n)
    last = np.maximum.accumulate(np.where(split, idx, -1))
    nxt = np.minimum.accumulate(np.where(split, idx, n)[::-1])[::-1]
    dist = np.minimum(idx - (last + 1), (nxt - 1) - idx) * step_m     # 0 at a record's first/last cell
    return ((dist < long_m) & ~split).astype(int)


def read_params(path: Path):
    """TgmsParams from a TOML file written by ``tune`` (keys of TgmsParams at top level)."""
    import tomllib

    from trolley.tgms.params import TgmsParams
    try:
        d = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{path}: cannot read parameters ({exc})") from None
    fmt = d.pop("format", None)
    if fmt is not None and fmt != PARAMS_FORMAT:
        raise ValueError(f"{path}: format must be \"{PARAMS_FORMAT}\", got {fmt!r}")
    d.pop("loglik", None)
    if not d:
        # an empty (or format-only) file would silently mean the defaults
        raise ValueError(f"{path}: no parameters (a file written by `trolley tgms tune`, or keys of "
                         "docs/tgms.md)")
    try:
        return TgmsParams.from_dict(d)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


#: how far below the cameras' frame rate process_rate_hz may lie, relative (timestamp rounding)
PROCESS_RATE_TOLERANCE = 0.01


def check_process_rate(params, rec, params_file: Path | None) -> None:
    """Refuse a processing rate below the camera frame rate (or below the default 100 Hz for faster
    cameras): each frame's attitude and trajectory would be interpolated between estimator samples
    farther apart than the frames, across the vehicle body's motion. Measured on the default
    simulated ride (200 m, 10 m/s, 100 Hz cameras): cross level 0.652 mm at 7 Hz, 0.066 at 25 Hz,
    0.033 at 50 Hz against 0.032 at 100 Hz; 100 Hz processing of 200 Hz cameras lost nothing
    (0.034 against 0.035 mm at 200 Hz). A refusal, like the file's other limits (bug hunt
    2026-11-27: process_rate_hz = 7.0 was accepted without a word)."""
    from survey.tgms_io import frame_period_s
    from trolley.tgms.params import TgmsParams

    camera_hz = 1.0 / frame_period_s(rec.lasers)
    need = min(camera_hz, TgmsParams().process_rate_hz)
    if params.process_rate_hz < need * (1.0 - PROCESS_RATE_TOLERANCE):
        where = f"{params_file}: parameter process_rate_hz" if params_file is not None else "process_rate_hz"
        raise ValueError(f"{where} = {params.process_rate_hz:g} Hz is below the camera frame rate ({camera_hz:.4g} Hz, "
                         f"laser_left.csv and laser_right.csv): each frame's attitude and trajectory would be "
                         f"interpolated between samples {1.0 / params.process_rate_hz:.3g} s apart; use at least "
                         f"{need:.4g} Hz")


def _params_file(path: Path) -> bool:
    """True for a parameter file that ``tune`` wrote (its first line names the format)."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.readline().strip() == f'format = "{PARAMS_FORMAT}"'
    except (OSError, UnicodeDecodeError):
        return False


PARAMS_FORMAT = "trolley-tgms-params/1"


def params_toml_text(params, extra: dict | None = None) -> str:
    lines = [f'format = "{PARAMS_FORMAT}"']
    for k, v in (extra or {}).items():
        lines.append(f"{k} = {v!r}")
    for k, v in params.to_dict().items():
        lines.append(f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {float(v)!r}")
    return "\n".join(lines) + "\n"


#: Memory of the simulation per camera frame, lasers, IMU and encoder between frames included,
#: bytes: measured 3.2 kB at 100 Hz and 2.7 kB at 300 Hz (tracemalloc peak over 200-400 m at
#: 5-10 m/s, less the 100 MB that does not grow with the length), rounded up.
_FRAME_BYTES = 4096


@tgms_app.command("simulate")
def simulate_cmd(
    out: Annotated[Path, typer.Option("--out", help="recording folder to write")],
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    length_m: Annotated[float, typer.Option("--length-m", help="track length ridden, m (>= 60)")] = 200.0,
    speed_m_s: Annotated[float, typer.Option("--speed-m-s", help="nominal speed, m/s (1-40)")] = 10.0,
    camera_rate_hz: Annotated[float, typer.Option("--camera-rate-hz", help="camera frame rate, Hz (5-500)")] = 100.0,
    rail_profile: Annotated[RailProfile, typer.Option("--rail-profile", help="rail profile (EN 13674-1)")] = "60E1",
    json_output: JsonAlways = False,
) -> None:
    """Write a synthetic TGMS recording folder plus truth.csv."""
    from survey import tgms_io
    from trolley.tgms.simulate import SimulationSettings, simulate
    st = SimulationSettings(length_m=length_m, speed_m_s=speed_m_s, seed=seed,
                            camera_rate_hz=camera_rate_hz, rail_profile=rail_profile)
    try:
        # the ranges here, not as typer min/max: nan got "Input should be greater than or equal to 60"
        check_finite(length_m, "--length-m", minimum=60.0)
        check_finite(speed_m_s, "--speed-m-s", minimum=1.0, maximum=40.0)
        check_finite(camera_rate_hz, "--camera-rate-hz", minimum=5.0, maximum=500.0)
        check_seed(seed)
        # before anything is allocated: --length-m 1e9 allocated until the memory ran out
        check_allocation(length_m / speed_m_s * camera_rate_hz, _FRAME_BYTES,
                         f"--length-m {length_m:g} at --speed-m-s {speed_m_s:g} and --camera-rate-hz {camera_rate_hz:g}")
        guard_overwrite(out, "tgms simulate", force=False, reuse_own=True)
    except ValueError as exc:
        _fail(str(exc))
    with console.status("simulating"):
        rec, truth = simulate(st)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with all_or_nothing():
            tgms_io.write_recording(out, rec)
            tgms_io.write_truth(out / "truth.csv", truth)
        write_marker(out, "tgms simulate")
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    n_frames = int(max(rec.lasers["left"].frame.max(), rec.lasers["right"].frame.max())) + 1
    jsonout.echo({"out": out, "seed": seed, "length_m": length_m, "speed_m_s": speed_m_s,
                  "duration_s": rec.imu_t_s[-1], "frames": n_frames,
                  "laser_points": len(rec.lasers["left"].frame) + len(rec.lasers["right"].frame)})


def _plots(out: Path, grid, band_label: str, truth: dict | None = None) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    files = []
    titles = {"gauge_variation": "Gauge variation (> 0 wider)", "cross_level": "Cross level (> 0 left rail higher)",
              "alignment": "Alignment (> 0 displaced right)", "vertical_profile": "Vertical profile (> 0 up)"}
    for name, title in titles.items():
        y = grid[f"{name}_mm"]
        fig, ax = plt.subplots(figsize=(10, 3.2))
        ax.plot(grid["s_m"], y, lw=0.8, color="C0", label="TGMS")
        if truth is not None:
            ax.plot(grid["s_m"], truth[f"{name}_mm"], lw=0.8, color="C3", ls="--", label="truth (truth.csv)")
            ax.legend(loc="upper right", fontsize=8)
        sig = grid.get(f"sigma_{name}_mm")
        if sig is not None and np.isfinite(sig).any() and band_label == "none":
            ax.fill_between(grid["s_m"], y - 1.96 * sig, y + 1.96 * sig, color="C0", alpha=0.2, lw=0,
                            label="95 % interval")
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("station s (m)")
        ax.set_ylabel(f"{name.replace('_', ' ')} (mm)")
        ax.set_title(f"{title}; band: {band_label}", fontsize=10)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        p = out / f"{name}.png"
        try:
            write_with(p, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
        finally:
            plt.close(fig)
        files.append(p.name)
    return files


@tgms_app.command("process")
def process_cmd(
    folder: Annotated[Path, typer.Argument(help="TGMS recording folder (FORMATS.md section 3)")],
    out: Annotated[Path, typer.Option("--out", help="output folder")],
    step: Annotated[float, typer.Option("--step-m", help="station step of the output, m (0.01-5)")] = 0.25,
    band: Annotated[str, typer.Option("--band", help="D1, D2, D3 (EN 13848 bands), none, SHORT-LONG in m (e.g. 3-25) "
                                                    "or a single number LONG in m (e.g. 3: keeps wavelengths from "
                                                    f"{BAND_MIN_STEPS:g} steps up to LONG, i.e. removes the longer "
                                                    f"ones); SHORT may not be below {BAND_MIN_STEPS:g} steps")] = "none",
    params_file: Annotated[Optional[Path], typer.Option("--params", help="parameter file from 'tgms tune'")] = None,
    orientation: Annotated[Optional[TgmsOrientation], typer.Option(help="attitude estimator (overrides --params; ignored with "
                                                            "--trajectory ekf, which estimates the attitude itself). "
                                                            "madgwick gives no roll covariance (docs/tgms.md)")] = None,
    trajectory: Annotated[Optional[TgmsTrajectory], typer.Option(help="trajectory estimator (overrides --params)")] = None,
    no_curve_matching: Annotated[bool, typer.Option("--no-curve-matching", help="use the encoder stations as they are")] = False,
    plots: Annotated[bool, typer.Option("--plots/--no-plots", help="write PNG plots into --out")] = True,
    json_output: JsonAlways = False,
    step_old: Annotated[Optional[float], typer.Option("--step", hidden=True, help=old_name("--step-m"))] = None,
) -> None:
    """Process a recording into irregularities.csv (+ PNG plots)."""
    import dataclasses

    import numpy as np

    from survey import tgms_io
    from trolley.bands import bandpass_wavelength
    from trolley.tgms.params import TgmsParams
    from survey.commands.progress import progress_bar, share
    from trolley.tgms.pipeline import process

    step_option = "--step" if step_old is not None else "--step-m"   # named as typed
    step = renamed(step, step_old, "--step-m", "--step", 0.25)
    try:
        check_finite(step, step_option, minimum=0.01, maximum=5.0)
        # the reader said "/tmp: cannot read parameters ([Errno 21] Is a directory: '/tmp')"
        check_file_option(params_file, "--params", "a parameter file", "params.toml",
                          "`trolley tgms tune DIR --out FILE` writes one")
        bounds = parse_band(band, step)
        check_outputs([], inputs=[folder], folders=[("--out", out)])
    except ValueError as exc:
        _fail(str(exc))
    params = TgmsParams()
    if params_file is not None:
        try:
            params = read_params(params_file)
        except ValueError as exc:
            _fail(str(exc))
    try:
        if orientation is not None or trajectory is not None:
            d = params.to_dict()
            if orientation is not None:
                d["orientation"] = orientation
            if trajectory is not None:
                d["trajectory"] = trajectory
            params = TgmsParams.from_dict(d)
    except ValueError as exc:
        _fail(str(exc))
    warnings = []
    if params.trajectory == "ekf" and orientation is not None:
        warnings.append(f"--orientation {orientation} is ignored: the 12-state smoother (--trajectory ekf) estimates "
                        "the attitude itself")
        _warn(warnings[-1])
    with progress_bar("reading the recording", console) as report:
        rec = _read_recording(folder)
        try:
            check_process_rate(params, rec, params_file)
        except ValueError as exc:
            _fail(str(exc))
        try:
            res = process(rec, params, step_m=step, match_curves=not no_curve_matching,
                          progress=share(report, 0.1, 1.0))
        except ValueError as exc:
            _fail(f"{folder}: {exc}")
        report("done", 1.0)
    for text in tgms_io.process_warnings(rec, res, step):
        warnings.append(text)
        _warn(text)
    g = res.grid
    cols = {"s_m": g.s_m}
    for name in g.NAMES:
        v = getattr(g, f"{name}_m")
        if bounds is not None:
            v = bandpass_wavelength(v, step, *bounds)
        cols[f"{name}_mm"] = v * 1e3
    if bounds is not None and all(np.isnan(cols[f"{n}_mm"]).all() for n in g.NAMES):
        length = float(g.s_m[-1] - g.s_m[0]) if len(g.s_m) else 0.0
        _fail(f"--band {band}: the record ({length:.1f} m) is too short for wavelengths up to {bounds[1]:g} m: "
              "every band-passed value would be empty; choose a shorter band (e.g. D1) or none")
    for name in g.NAMES:
        cols[f"sigma_{name}_mm"] = getattr(g, f"sigma_{name}_m") * 1e3
    if bounds is not None:
        cols["band_edge"] = np.max([band_edge_flags(cols[f"{n}_mm"], step, *bounds) for n in g.NAMES], axis=0)
    truth_path = folder / "truth.csv"
    truth = truth_on_grid = None
    if truth_path.exists():
        try:
            truth = tgms_io.read_truth(truth_path)
        except tgms_io.TgmsFormatError as exc:
            _fail(str(exc))
        truth_on_grid = {}
        for name in g.NAMES:
            v = np.interp(g.s_m, truth["s_m"], truth[f"{name}_mm"])
            v = np.where(np.isfinite(cols[f"{name}_mm"]) | (bounds is None), v, np.nan)
            if bounds is not None:
                v = bandpass_wavelength(np.where(np.isfinite(getattr(g, f"{name}_m")), v, np.nan), step, *bounds)
            truth_on_grid[f"{name}_mm"] = v
    try:
        out.mkdir(parents=True, exist_ok=True)
        with all_or_nothing():
            tgms_io.write_irregularities(out / "irregularities.csv", cols)
            files = ["irregularities.csv"]
            if plots:
                label = "none" if bounds is None else f"{bounds[0]:g}-{bounds[1]:g} m"
                files += _plots(out, cols, label, truth_on_grid)
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    summary = {
        "out": str(out), "files": files, "rows": int(len(g.s_m)),
        "frames": int(len(res.vision.frame)), "frames_flagged": int((~res.vision.ok).sum()),
        "empty_cells": {n: int(np.isnan(cols[f"{n}_mm"]).sum()) for n in g.NAMES},   # (after --band)
        "curve_anchors": [[float(a), float(d)] for a, d in zip(res.odometry.anchors_app_m, res.odometry.anchors_design_m)],
        "params": dataclasses.asdict(params), "timings_s": res.timings_s, "warnings": warnings,
    }
    if truth is not None:
        from trolley.tgms.accuracy import accuracy
        acc = accuracy(res.frames, truth, res.vision.t_s, step, laser_offset_m=res.laser_offset_m)
        summary["accuracy_3_25m"] = dataclasses.asdict(acc)
    jsonout.echo(summary)


@tgms_app.command("tune")
def tune_cmd(
    folder: Annotated[Path, typer.Argument(help="TGMS recording folder")],
    out: Annotated[Path, typer.Option("--out", help="parameter file to write (TOML)")],
    evaluations: Annotated[int, typer.Option(min=10, max=2000, help="likelihood evaluations")] = 60,
    seed: Annotated[int, typer.Option(min=0, max=2**32 - 1, help="seed of the global optimiser")] = 0,
    model: Annotated[TgmsModel, typer.Option(help="kf (attitude filter), ltv (attitude filter, then the Eq. 46 "
                                             "trajectory under Eq. 19) or ekf (12-state smoother)")] = "kf",
    box: Annotated[TgmsBox, typer.Option(help="search box: relative (4 decades around the defaults) or absolute "
                                              "(1e-4..1e4 in the paper's variances, Eq. 17; excludes a MEMS gyro's "
                                              "true noise at 100 Hz)")] = "relative",
    json_output: JsonAlways = False,
) -> None:
    """Constrained maximum-likelihood estimation of the noise parameters (Gonzalez-Carbajal 2023 Sec. 4.2).
    --evaluations is a hard limit on the filter runs."""
    import numpy as np

    from survey.commands.progress import progress_bar
    from trolley.tgms.tuning import tune_cml

    try:
        check_outputs([("--out", out)], inputs=[folder / "tgms.toml"], made_before=_params_file)
    except OutputError as exc:
        _fail(str(exc))
    with progress_bar("reading the recording", console) as report:
        rec = _read_recording(folder)
        try:
            params, info = tune_cml(rec, max_evaluations=evaluations, seed=seed, model=model, box=box,
                                    progress=report)
        except ValueError as exc:
            _fail(f"{folder}: {exc}")
    if not np.isfinite(info["loglik"]) or info["loglik"] <= -1e29:
        _fail(f"{folder}: no parameter set in the box satisfied the constraints within {evaluations} evaluations")
    if info["loglik"] <= info["loglik_default"]:
        console.print(f"note: nothing in the search box within {evaluations} evaluations beat the defaults (log-"
                      f"likelihood {info['loglik_default']:.1f}): {out} holds the defaults", highlight=False,
                      markup=False, soft_wrap=True)
    try:
        write_text_atomic(out, params_toml_text(params, {"loglik": float(info["loglik"])}))
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    jsonout.echo({"out": out, "params": params.to_dict(), **info})


def register(app: typer.Typer) -> None:
    """Add the ``tgms`` command group to the ``trolley`` app."""
    app.add_typer(tgms_app, name="tgms")
