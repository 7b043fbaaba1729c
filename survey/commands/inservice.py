"""``trolley inservice ...``: lateral track alignment from inertial sensors on an in-service vehicle
(Munoz 2021).

* ``trolley inservice simulate --out DIR`` writes a synthetic recording and truth.csv
  (survey/commands/inservice_simulate.py).
* ``trolley inservice calibrate --out model.toml [--kind bogie|paper] [--sensor-gravity]`` runs the
  full-vehicle truth simulator (the paper's reference simulation with the complete model),
  identifies the design model's suspension (Eq. 6), estimates Q and R (Eq. 26-29) and tunes the
  filter (docs/inservice.md). ``bogie`` (default) is the bogie design model of
  trolley.inservice.bogie, ``paper`` the simplified model of Munoz 2021. ``--sensor-gravity``: the
  accelerometers sense g times their roll, as real ones do, and the filter gains the cross-level
  roll (trolley.inservice.model.with_sensor_gravity).
* ``trolley inservice vehicle --out FILE`` writes the default vehicle as a vehicle file to edit;
  ``simulate`` and ``calibrate`` take one with ``--vehicle FILE`` (survey/inservice_vehicle.py), and
  ``process --model`` says when the recording's [vehicle] differs from the model's.
* ``trolley inservice process RECORDING --out DIR [--truth FILE] [--model FILE] [--smoother rts|none]``
  writes irregularities.csv (s_m, alignment_mm, sigma_alignment_mm, and the alignment band-passed
  to 3-200 m with its own sigma; alignment positive to the RIGHT as in every project file),
  summary.json (J/Jrel per EN 13848 band with --truth), alignment.png and inservice.xlsx (one
  sheet in the survey workbook's style).

Bad input: a message naming the file/row/column or key on stderr, exit 2, no output written.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console

from survey import jsonout
from survey.atomicwrite import OutputError, all_or_nothing, check_outputs, remove_stale_temporaries, write_with
from survey.commands.inservice_simulate import (VehicleOption, _fail, check_vehicle_option, simulate_cmd, vehicle_cmd,
                                                vehicle_for_run)
from survey.commands.options import InserviceKind, InserviceSmoother, JsonAlways
from survey.limits import MAX_SEED, check_allocation, check_file_option, check_finite, check_integer, check_seed

console = Console(stderr=True)

inservice_app = typer.Typer(help="In-service vehicle: wheelset/bogie inertial sensors -> lateral alignment.",
                            no_args_is_help=True)
inservice_app.command("simulate")(simulate_cmd)
inservice_app.command("vehicle")(vehicle_cmd)

#: output grid step of irregularities.csv, m, and the decimals of its chainage column
OUTPUT_STEP_M = 0.25
CHAINAGE_DECIMALS = 4
#: shortest calibration run, m: the tuning's J over 3-200 m starts after the filter's 30 m start-up
MIN_CALIBRATION_LENGTH_M = 250.0
#: a filter rate within this fraction of a model's calibration rate is that rate (a logger's clock
#: is some 10-100 ppm off its nominal rate; the filter's own uniformity check allows 1e-3)
SAME_RATE_TOLERANCE = 1e-3
#: the files `process` writes into --out
OUTPUT_NAMES = ("irregularities.csv", "alignment.png", "inservice.xlsx", "summary.json")
#: the sensor channels as named in messages
SENSOR_LABELS = ("wheelset accelerometer", "wheelset gyro", "frame accelerometer")
#: and as keys of summary.json
CONSISTENCY_KEYS = ("wheelset_ay", "wheelset_wz", "frame_ay")

#: memory of `process` beyond the recording's samples: the libraries, one block's forward-filter
#: window, smoother and band sigma (estimator.estimate_in_blocks; measured with /usr/bin/time -v,
#: docs/inservice.md "Long recordings"), bytes
PROCESS_BASE_BYTES = 1.4e9


def process_memory_bytes(samples: int, n_state: int) -> float:
    """Peak memory `process` needs for a recording of ``samples`` samples at the filter rate and a
    design model of ``n_state`` states, bytes (an estimate, on the large side): one block's window
    (the base) and per sample the recording, the estimate's columns and the outputs (measured with
    the bogie model, 20 states, 2-10 km: 1.8 kB per sample above 1.3 GB)."""
    return PROCESS_BASE_BYTES + samples * (2500.0 + 4.0 * n_state ** 2)


def _write_png(path: Path, cols: dict, truth_mm=None, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from trolley.bands import bandpass_wavelength

    s_m, est_mm, sig_mm = cols["s_m"], cols["alignment_mm"], cols["sigma_alignment_mm"]
    band = [k for k in cols if k.startswith("alignment_") and k != "alignment_mm"]
    step = float(s_m[1] - s_m[0])
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), dpi=110, sharex=True)
    ax = axes[0]
    ax.fill_between(s_m, est_mm - 2 * sig_mm, est_mm + 2 * sig_mm, color="tab:blue", alpha=0.2, lw=0,
                    label="estimate +- 2 sigma")
    ax.plot(s_m, est_mm, lw=0.9, color="tab:blue", label="estimate")
    if truth_mm is not None:
        ax.plot(s_m, truth_mm, lw=0.8, color="k", label="truth")
    ax.set_ylabel("alignment, unfiltered [mm]")
    ax.set_title(title)
    ax = axes[1]
    if band:
        b, sb = cols[band[0]], cols["sigma_" + band[0]]
        ax.fill_between(s_m, b - 2 * sb, b + 2 * sb, color="tab:blue", alpha=0.2, lw=0, label="estimate +- 2 sigma")
        ax.plot(s_m, b, lw=0.9, color="tab:blue", label="estimate 3-200 m")
        if truth_mm is not None:
            ax.plot(s_m, bandpass_wavelength(truth_mm, step, 3.0, 200.0), lw=0.8, color="k", label="truth 3-200 m")
    ax.set_ylabel("alignment 3-200 m [mm]")
    ax.set_xlabel("chainage [m]  (alignment positive to the right)")
    for a in axes:
        a.grid(True, lw=0.4, alpha=0.6)
        if a.get_legend_handles_labels()[0]:
            a.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    try:
        write_with(path, lambda tmp: fig.savefig(tmp))
    finally:
        plt.close(fig)


def _worst_sensor(cons: dict) -> tuple[str, float]:
    """The sensor with the largest innovation ratio in a checked summary consistency: (label, ratio)."""
    key, worst = max(cons["innovation_rms_ratio"].items(), key=lambda kv: kv[1])
    return SENSOR_LABELS[CONSISTENCY_KEYS.index(key)], worst


def _consistency_text(cons: dict) -> str:
    """The summary's consistency check in words, for the workbook."""
    if not cons["checked"]:
        return f"not checked: {cons['reason']}"
    label, worst = _worst_sensor(cons)
    quiet, least = _quietest_sensor(cons)
    if cons["consistent"]:
        return f"fits the calibration (largest innovation ratio {worst:.2f} <= {cons['limit']:g}, {label})"
    if worst <= cons["limit"]:
        return (f"DOES NOT FIT the calibration: {quiet} innovations {least:.2f} x the calibration's (< "
                f"{cons['low']:g}): a sensor silent or read at a wrong scale?")
    return (f"DOES NOT FIT the calibration: {label} innovations {worst:.2f} x the calibration's "
            f"(> {cons['limit']:g}); the sigmas cannot be trusted")


def _quietest_sensor(cons: dict) -> tuple[str, float]:
    """The sensor with the smallest innovation ratio in a checked summary consistency: (label, ratio)."""
    key, least = min(cons["innovation_rms_ratio"].items(), key=lambda kv: kv[1])
    return SENSOR_LABELS[CONSISTENCY_KEYS.index(key)], least


def _vehicle_text(check: dict) -> str:
    """The summary's vehicle check in words, for the workbook and the warning."""
    if not check["checked"]:
        return f"not checked: {check['reason']}"
    if check["matches"]:
        return "the recording's vehicle is the model's"
    diffs = ", ".join(f"{k} {d['recording']:.10g} (model {d['model']:.10g})" for k, d in check["differences"].items())
    return f"DIFFERS from the model's vehicle: {diffs}; calibrate for this vehicle (--vehicle)"


def _speed_text(check: dict) -> str:
    """The summary's speed check in words, for the workbook and the warning."""
    if not check["checked"]:
        return f"not checked: {check['reason']}"
    lo, hi, vc = check["recording_low_m_s"], check["recording_high_m_s"], check["calibration_m_s"]
    speeds = f"{lo:.3g} m/s" if f"{lo:.3g}" == f"{hi:.3g}" else f"{lo:.3g}-{hi:.3g} m/s"
    if check["fits"]:
        return f"recorded at {speeds}, within {check['tolerance']:.0%} of the calibration's {vc:g} m/s"
    return (f"recorded at {speeds}, DIFFERS by more than {check['tolerance']:.0%} from the calibration's {vc:g} "
            f"m/s; calibrate at the recording's speed (--speed-m-s)")


def _write_xlsx(path: Path, recording: str, summary: dict, cols: dict) -> None:
    """One sheet in the survey workbook's style: a header row, the summary row, then the profile."""
    from openpyxl import Workbook

    from survey.sheet_text import put_text
    from survey.workbook import _header, _num

    wb = Workbook()
    ws = wb.active
    ws.title = "Alignment"
    bands = list(summary.get("accuracy", {}))
    # (name, text or number): the client reads this row without summary.json, so an uncalibrated
    # model says so here too, not only on the terminal
    model = summary["model"] if summary["calibrated"] else (
        f"UNCALIBRATED: {summary['model']}, default noise; neither the accuracy nor honest sigmas "
        "(trolley inservice calibrate)")
    row = [("recording", recording), ("length_m", summary["length_m"]), ("speed_m_s", summary["speed_m_s"]),
           ("smoother", summary["smoother"]), ("model", model), ("cpu_s", summary["cpu_s"]),
           ("real_time_ratio", summary["real_time_ratio"])]
    row += [(f"J_{b}_mm", summary["accuracy"][b]["J_mm"]) for b in bands]
    row += [(f"Jrel_{b}", summary["accuracy"][b]["Jrel"]) for b in bands]
    row += [("model_check", _consistency_text(summary["consistency"])),
            ("vehicle_check", _vehicle_text(summary["vehicle_check"])),
            ("speed_check", _speed_text(summary["speed_check"]))]
    _header(ws, 1, [name for name, _ in row])
    for j, (_, v) in enumerate(row, start=1):
        if isinstance(v, str):
            put_text(ws, 2, j, v)
        else:
            _num(ws, 2, j, v, "0.000")
    _header(ws, 4, list(cols))
    for j, (name, values) in enumerate(cols.items(), start=1):
        fmt = "0.00" if name == "s_m" else "0.000"
        for i, v in enumerate(values, start=5):
            _num(ws, i, j, v, fmt)
    ws.freeze_panes = "A5"
    ws.page_setup.paperSize = ws.PAPERSIZE_A4
    ws.page_setup.fitToWidth, ws.page_setup.fitToHeight = 1, 0
    ws.sheet_properties.pageSetUpPr.fitToPage = True
    ws.print_title_rows = "4:4"
    write_with(path, lambda tmp: wb.save(tmp))


def _builtin_model_for(rec):
    """The built-in calibration (survey.inservice_model.BUILTIN_MODEL_PATH) when it is the recording's
    vehicle and accelerometers, else None; with the label summary.json gives the model and the note
    that says on stderr which model is used and why."""
    from survey.inservice_io import vehicle_differences
    from survey.inservice_model import BUILTIN_MODEL_PATH, model_provenance, read_model
    from trolley.inservice.vehicle import DEFAULT_VEHICLE_NAME

    builtin = read_model(BUILTIN_MODEL_PATH)
    prov = model_provenance(BUILTIN_MODEL_PATH)
    diffs = vehicle_differences(rec, builtin.params)
    if rec.vehicle_name is not None and rec.vehicle_name != DEFAULT_VEHICLE_NAME:
        # a vehicle file may differ in values the recording's [vehicle] does not hold
        why = (f"its vehicle is {rec.vehicle_name!r}, the built-in model's {DEFAULT_VEHICLE_NAME!r}; calibrate for "
               "it with `trolley inservice calibrate --vehicle FILE`")
    elif rec.sense_gravity != bool(builtin.params.sensor_gravity):
        why = ("its accelerometers sense gravity (sensors.accelerometers_sense_gravity); calibrate with "
               "`trolley inservice calibrate --sensor-gravity`")
    elif diffs:
        keys = list(diffs)
        why = (f"its [vehicle] differs from the built-in vehicle's in {len(keys)} key{'s' * (len(keys) > 1)} ("
               + ", ".join(keys[:4]) + (", ..." if len(keys) > 4 else "")
               + "); calibrate for it with `trolley inservice calibrate --vehicle FILE`")
    else:
        return builtin, f"built-in ({prov})", (f"note: no --model given: the built-in model, {prov}, which is this "
                                               "recording's vehicle")
    return None, "nominal (recording [vehicle])", (
        f"note: no --model given, and the built-in model does not fit the recording: {why}. Until then the "
        "recording's uncalibrated nominal parameters with default noise are used; they give neither the accuracy "
        "nor the honest sigmas of docs/inservice.md")


@inservice_app.command("process")
def process_cmd(
    recording: Annotated[Path, typer.Argument(help="recording folder (inservice.toml + sensors.csv)")],
    out: Annotated[Path, typer.Option("--out", help="output folder")],
    truth: Annotated[Optional[Path], typer.Option("--truth", help="truth.csv: adds J/Jrel per band to summary.json")] = None,
    model: Annotated[Optional[Path], typer.Option(
        "--model", help="model.toml from `trolley inservice calibrate` (default: the built-in calibration when the "
                        "recording is of the built-in vehicle, else the recording's nominal parameters with default "
                        "noise, uncalibrated)")] = None,
    smoother: Annotated[InserviceSmoother, typer.Option(
        "--smoother", help="rts (forward filter + RTS smoother) or none (the paper's forward filter)")] = "rts",
    filter_rate_hz: Annotated[float, typer.Option(
        "--filter-rate-hz",
        help="faster recordings are low-passed and decimated to no less than this rate first (20-5000 Hz)")] = 200.0,
    json_output: JsonAlways = False,
) -> None:
    """Estimate the lateral alignment from a recording (Munoz 2021 Kalman filter, plus an RTS smoother)."""
    import numpy as np

    from survey.inservice_io import (InserviceFormatError, bogie_nominal, read_recording, read_truth,
                                     vehicle_differences)
    from survey.inservice_model import ModelFileError, read_model
    from survey.atomicwrite import write_text_atomic
    from survey.sessionio import write_csv_columns
    from trolley import units
    from trolley.inservice.accuracy import band_accuracy, honesty, uniform_grid
    from trolley.inservice.bogie import BogieParameters
    from trolley.inservice.estimator import SETTLE_M, NoiseDensities, estimate_in_blocks
    from trolley.inservice.identification import HONESTY_BAND_M, model_consistency, speed_fits
    from trolley.inservice.model import ModelParameters
    from trolley.inservice.resample import decimated, decimation_factor

    try:
        # the range here, not as typer min/max: nan got "Input should be less than or equal to 5000"
        check_finite(filter_rate_hz, "--filter-rate-hz", minimum=20.0, maximum=5000.0)
    except ValueError as exc:
        _fail(str(exc))
    try:
        check_file_option(model, "--model", "a model file", "model.toml",
                          "`trolley inservice calibrate --out FILE` writes one")
        check_file_option(truth, "--truth", "a truth file", "truth.csv",
                          "`trolley inservice simulate --out OUT` writes OUT/truth.csv")
        check_outputs([], inputs=[recording, truth, model], folders=[("--out", out)])
        if out.is_dir():
            check_outputs([("--out", out / name) for name in OUTPUT_NAMES], inputs=[truth, model])
        rec = read_recording(recording)
        tru = read_truth(truth) if truth is not None else None
        mdl = read_model(model) if model is not None else None
    except (InserviceFormatError, ModelFileError, OutputError, ValueError) as exc:
        _fail(str(exc))
    if len(rec.t_s) < 10:
        _fail(f"{recording / 'sensors.csv'}: needs at least 10 rows, got {len(rec.t_s)}")
    for note in rec.notes:
        console.print(f"warning: {note}", highlight=False, markup=False, soft_wrap=True)
    # (a chainage that does not increase is refused by read_recording, naming its row and why)
    dt = float(np.median(np.diff(rec.t_s)))       # (uniform: read_recording checks it)
    if tru is not None and (tru["s_m"][0] > rec.s_m[0] + 1e-6 or tru["s_m"][-1] < rec.s_m[-1] - 1e-6):
        _fail(f"{truth}: column s_m covers {tru['s_m'][0]:.2f}-{tru['s_m'][-1]:.2f} m, "
              f"the recording {rec.s_m[0]:.2f}-{rec.s_m[-1]:.2f} m")
    model_label = str(model) if model else None
    if mdl is None:
        mdl, model_label, default_note = _builtin_model_for(rec)
        console.print(default_note, highlight=False, markup=False, soft_wrap=True)
    if smoother == "none":
        # measured (docs/inservice.md, "The paper's estimator"; bug hunt 2026-11-26): Jrel about 1
        console.print("warning: --smoother none is the paper's forward filter alone: calibrate tunes the model for "
                      "the smoother, and with such a model the forward filter's estimate is no better than zero "
                      "(Jrel 1.0 on the benchmark; 1.5 mm rms even with a model tuned for it)",
                      highlight=False, markup=False, soft_wrap=True)
    z = np.column_stack([rec.wheelset_ay_m_s2, rec.wheelset_wz_rad_s, rec.frame_ay_m_s2])
    import filterpy.kalman  # noqa: F401  (imported before the clock: the speed is the filter's)
    import scipy.linalg  # noqa: F401
    t0 = time.process_time()
    q = decimation_factor(1.0 / dt, filter_rate_hz)
    if mdl is None:
        bog = bogie_nominal(rec)
        params = BogieParameters(**bog) if bog is not None else ModelParameters(**rec.nominal)
    n_state = (mdl.params if mdl is not None else params).n_state
    try:
        # before the filter's arrays: a recording too long for this machine is refused, not swapped
        samples = (len(rec.t_s) + q - 1) // q
        check_allocation(samples, process_memory_bytes(samples, n_state) / samples,
                         f"{recording / 'sensors.csv'}: {len(rec.t_s)} samples over "
                         f"{float(rec.s_m[-1] - rec.s_m[0]):.0f} m ({samples} at the filter rate, {n_state} states)",
                         advice="process the recording in shorter parts")
    except ValueError as exc:
        _fail(str(exc))
    try:
        (t_f, s_f, v_f), z = decimated(q, [rec.t_s, rec.s_m, rec.speed_arr_m_s], z)
    except ValueError as exc:
        _fail(f"{recording / 'sensors.csv'}: {exc}")
    length = float(rec.s_m[-1] - rec.s_m[0])
    xi_true = np.interp(s_f, tru["s_m"], tru["alignment_m"]) if tru is not None else None
    # the filter, the smoother and the band sigma in blocks of estimator.BAND_BLOCK_M: the memory
    # is the block's, whatever the recording's length (docs/inservice.md, "Long recordings")
    band_m = HONESTY_BAND_M if length >= HONESTY_BAND_M[1] else None
    if mdl is not None:
        # a logger's clock a few ppm off (or the mean of jittered time stamps) is the calibration's
        # rate: at_dt would drop the consistency reference and warn of a J several times larger
        m = mdl if abs(dt * q / mdl.dt_s - 1.0) <= SAME_RATE_TOLERANCE else mdl.at_dt(dt * q)
        if m is not mdl:
            # the rescaling of Q, R and S with dt is first order: measured on the benchmark (bug hunt
            # 2026-11-26) J grows 2-4 times (0.31 -> 0.71 mm at 1000 Hz, 1.10 mm at 200 Hz with a
            # 100 Hz model)
            # (bug hunt 26b) with a 1000 Hz model the sigmas of a 200 Hz recording were half the error
            # (seed 1), and "use --filter-rate-hz 1000" cannot speed up a 200 Hz recording: that
            # advice only where the model's rate is the recording's divided by a whole number
            model_hz, rec_hz = 1.0 / mdl.dt_s, 1.0 / dt
            whole = max(1, round(rec_hz / model_hz))
            fix = f"calibrate at this rate (--rate-hz {rec_hz:g} --filter-rate-hz {filter_rate_hz:g})"
            if abs(rec_hz / whole / model_hz - 1.0) <= SAME_RATE_TOLERANCE:
                fix = f"use --filter-rate-hz {model_hz:g} or " + fix
            console.print(f"warning: the filter runs at {1.0 / (dt * q):g} Hz and the model was calibrated at "
                          f"{model_hz:g} Hz: J can be several times the calibrated one and its sigmas too "
                          f"small; {fix}", highlight=False, markup=False, soft_wrap=True)
        scale, kind = m.sigma_scale, m.params.KIND
        est = estimate_in_blocks(m.params, t_f, s_f, v_f, z, band_m, scale, xi_true, Q=m.Q, R=m.R, S=m.S,
                                 curvature_1_m=rec.curvature_1_m or None, smoother=smoother)
        fit, not_checked = None, None
        if mdl.innovation_rms is None:
            not_checked = "the model file has no innovation reference (calibrated before the check existed)"
        elif m.innovation_rms is None:
            not_checked = "the filter rate differs from the calibration's"
        elif s_f[-1] - s_f[0] <= 2 * SETTLE_M:
            not_checked = f"the recording is not longer than {2 * SETTLE_M:g} m"
        else:
            fit = model_consistency(est, m)
    else:
        fit, not_checked = None, "no calibrated model (--model)"
        # the sensors' white noise per sample, after decimation by q
        noise = NoiseDensities(sigma_acc_m_s2=max(rec.sigma_acc_m_s2, 1e-4) / np.sqrt(q),
                               sigma_gyro_rad_s=max(rec.sigma_gyro_rad_s, 1e-6) / np.sqrt(q))
        scale, kind = 1.0, params.KIND
        est = estimate_in_blocks(params, t_f, s_f, v_f, z, band_m, scale, xi_true, noise=noise,
                                 curvature_1_m=rec.curvature_1_m or None, smoother=smoother)
    band = est.band
    cpu = time.process_time() - t0
    sig = est.sigma_alignment_m * scale
    grid, (a_g, s_g) = uniform_grid(s_f, est.alignment_m, sig, step_m=OUTPUT_STEP_M)
    duration = float(rec.t_s[-1] - rec.t_s[0])
    summary = {"recording": str(recording), "samples": int(len(rec.t_s)), "length_m": length,
               "speed_m_s": float(np.mean(rec.speed_arr_m_s)), "curvature_1_m_right_positive": -rec.curvature_1_m,
               "smoother": smoother, "model": model_label,
               "design_model": kind, "sensor_gravity": bool(mdl.params.sensor_gravity) if mdl is not None else False,
               "recording_accelerometers_sense_gravity": rec.sense_gravity,
               "calibrated": mdl is not None, "sensor_rate_hz": 1.0 / dt,
               "filter_rate_hz": 1.0 / (dt * q), "blocks": est.blocks, "cpu_s": round(cpu, 4), "duration_s": duration,
               "real_time_ratio": round(duration / cpu, 1) if cpu > 0 else None,
               "recording_notes": list(rec.notes)}
    if mdl is None:
        summary["vehicle_check"] = {"checked": False, "reason": "no calibrated model (--model)"}
        summary["speed_check"] = {"checked": False, "reason": "no calibrated model (--model)"}
    else:
        sc = speed_fits(mdl, rec.speed_arr_m_s)
        summary["speed_check"] = {"checked": False, "reason": "the model file has no calibration speed (calibrated "
                                  "before the check existed)"} if sc is None else {
            "checked": True, "calibration_m_s": sc.calibration_m_s, "recording_low_m_s": sc.low_m_s,
            "recording_high_m_s": sc.high_m_s, "tolerance": sc.tolerance, "fits": sc.fits}
        if sc is not None and not sc.fits:
            console.print(f"warning: {recording / 'sensors.csv'}: " + _speed_text(summary["speed_check"]).replace(
                "DIFFERS", "differs", 1) + "; J and the sigmas are those of another speed (docs/inservice.md, "
                "\"Speed of the calibration\")", highlight=False, markup=False, soft_wrap=True)
        diffs = vehicle_differences(rec, mdl.params)
        summary["vehicle_check"] = {"checked": True, "matches": not diffs, "differences": {
            k: {"recording": a, "model": b} for k, (a, b) in diffs.items()}}
        if diffs:
            console.print(f"warning: {recording / 'inservice.toml'}: [vehicle] "
                          + _vehicle_text(summary["vehicle_check"]).replace("DIFFERS", "differs", 1)
                          + "; the estimate and its sigmas are for the model's vehicle",
                          highlight=False, markup=False, soft_wrap=True)
        if rec.sense_gravity != bool(mdl.params.sensor_gravity):
            console.print(f"warning: {recording / 'inservice.toml'}: sensors.accelerometers_sense_gravity is "
                          f"{str(rec.sense_gravity).lower()}, the model was calibrated "
                          f"{'with' if mdl.params.sensor_gravity else 'without'} --sensor-gravity; the estimate and "
                          "its sigmas are for the model's accelerometers", highlight=False, markup=False, soft_wrap=True)
    summary["consistency"] = {"checked": False, "reason": not_checked} if fit is None else {
        "checked": True, "innovation_rms_ratio": dict(zip(CONSISTENCY_KEYS, map(float, fit.ratio))),
        "limit": fit.limit, "low": fit.low, "consistent": fit.consistent}
    if fit is not None and not fit.consistent and _worst_sensor(summary["consistency"])[1] <= fit.limit:
        console.print("warning: the recording does not fit the calibrated model: "
                      + _consistency_text(summary["consistency"]).split(": ", 1)[1]
                      + "; the estimate is not to be trusted", highlight=False, markup=False, soft_wrap=True)
    elif fit is not None and not fit.consistent:
        label, worst = _worst_sensor(summary["consistency"])
        console.print(f"warning: the recording does not fit the calibrated model: the {label}'s "
                      f"normalized innovations are {worst:.2f} times the calibration runs' (limit "
                      f"{fit.limit:g}): the wheel-rail contact, the curvature or the speed differ from the calibration "
                      "runs', and the sigmas cannot be trusted; calibrate for these conditions (docs/inservice.md, "
                      "\"Does the recording fit the model?\")",
                      highlight=False, markup=False, soft_wrap=True)
    elif mdl is not None and not_checked:
        console.print(f"note: model consistency not checked: {not_checked}", highlight=False, markup=False,
                      soft_wrap=True)
    truth_mm = None
    if tru is not None:
        acc = band_accuracy(s_f, est.alignment_m, xi_true)
        summary["accuracy"] = {b: {"J_mm": units.m_to_mm(a.J_m), "Jrel": a.Jrel, "rms_true_mm": units.m_to_mm(a.rms_true_m)}
                               for b, a in acc.items()}
        settle = s_f >= s_f[0] + SETTLE_M
        summary["honesty_rms_error_over_sigma"] = None     # (no 3-200 m band below 200 m: null, said)
        if band is not None:
            bs = band[0] >= band[0][0] + SETTLE_M
            summary["honesty_rms_error_over_sigma"] = honesty(band[1][bs], band[2][bs], band[3][bs])
        summary["honesty_unfiltered_rms_error_over_sigma"] = honesty(est.alignment_m[settle], sig[settle],
                                                                     xi_true[settle])
        truth_mm = -units.m_to_mm(np.interp(grid, tru["s_m"], tru["alignment_m"]))
    # files: alignment positive to the RIGHT (FRD, docs/conventions.md)
    est_mm, sig_mm = -units.m_to_mm(a_g), units.m_to_mm(s_g)
    cols = {"s_m": grid, "alignment_mm": est_mm, "sigma_alignment_mm": sig_mm}
    lo, hi = (f"{v:g}" for v in HONESTY_BAND_M)
    if band is not None:
        cols[f"alignment_{lo}_{hi}m_mm"] = -units.m_to_mm(np.interp(grid, band[0], band[1]))
        cols[f"sigma_alignment_{lo}_{hi}m_mm"] = units.m_to_mm(np.interp(grid, band[0], band[2]))
    try:
        out.mkdir(parents=True, exist_ok=True)
        # a run killed while writing left its hidden temporaries (a full copy of each output)
        remove_stale_temporaries(out, OUTPUT_NAMES)
        with all_or_nothing():
            # the chainage to 0.1 mm whatever its size (%.6g wrote 123456.25 m as 123456: four rows
            # per metre with one chainage); the millimetres to six significant digits; empty cells
            # where a value does not exist (sessionio's per-column writer, as track.csv)
            formats = [f"%.{CHAINAGE_DECIMALS}f" if name == "s_m" else "%.6g" for name in cols]
            write_with(out / "irregularities.csv", lambda tmp: write_csv_columns(
                tmp, list(cols), [np.asarray(v, dtype=float) for v in cols.values()], formats, nan_as_empty=True))
            run_name = f"{recording.resolve().parent.name}/{recording.name}"
            _write_png(out / "alignment.png", cols, truth_mm, title=f"lateral alignment - {run_name}")
            _write_xlsx(out / "inservice.xlsx", str(recording), {**summary, "accuracy": summary.get("accuracy", {})},
                        cols)
            # jsonout: a band longer than a short recording has no J (null, not NaN: valid JSON)
            write_text_atomic(out / "summary.json", jsonout.dumps(summary, indent=2) + "\n")
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    jsonout.echo(summary)


@inservice_app.command("calibrate")
def calibrate_cmd(
    out: Annotated[Path, typer.Option("--out", help="model.toml to write")],
    speed_m_s: Annotated[float, typer.Option("--speed-m-s", help="speed of the reference run, m/s (2-60)")] = 20.0,
    length_m: Annotated[float, typer.Option(
        "--length-m",
        help="reference run length, m (250-5000: the 3-200 m band after the filter's start-up needs 250 m)")] = 400.0,
    seed: Annotated[int, typer.Option(help="seed of the reference run (use another one for evaluation)")] = 1000,
    rate_hz: Annotated[float, typer.Option("--rate-hz", help="sensor rate, Hz (20-2000)")] = 200.0,
    filter_rate_hz: Annotated[float, typer.Option(
        "--filter-rate-hz",
        help="faster runs are low-passed and decimated to no less than this rate, as `process` does (20-5000 Hz)")] = 200.0,
    extra_runs: Annotated[int, typer.Option("--extra-runs", min=0, max=20,
                                            help="further runs (seeds SEED+1...) the sigma scale is pooled "
                                                 "over")] = 3,
    kind: Annotated[InserviceKind, typer.Option(
        "--kind", help="design model of the filter: bogie (both wheelsets, the frame's yaw and the car body; "
                       "beyond the paper) or paper (Munoz 2021's one-wheelset model)")] = "bogie",
    sensor_gravity: Annotated[bool, typer.Option(
        "--sensor-gravity", help="the accelerometers sense g x their roll, as real ones do: the runs are simulated so "
                                 "and the filter gains the cross-level roll (not in the paper's virtual sensors)")] = False,
    vehicle: VehicleOption = None,
    json_output: JsonAlways = False,
) -> None:
    """Identify and tune the estimator on one reference run of the full-vehicle simulator (Munoz 2021 Sec. III-D, IV-B)."""
    from dataclasses import replace

    from survey.inservice_model import write_model
    from trolley.inservice.bogie import nominal_parameters
    from trolley.inservice.identification import calibrate
    from trolley.inservice.irregularity import irregularity_from_psd
    from trolley.inservice.resample import decimation_factor
    from trolley.inservice.vehicle import simulate_run

    try:
        # the ranges here, not as typer min/max: nan got "Input should be less than or equal to 60"
        check_finite(speed_m_s, "--speed-m-s", minimum=2.0, maximum=60.0)
        check_finite(length_m, "--length-m", minimum=MIN_CALIBRATION_LENGTH_M, maximum=5000.0)
        check_finite(rate_hz, "--rate-hz", minimum=20.0, maximum=2000.0)
        check_finite(filter_rate_hz, "--filter-rate-hz", minimum=20.0, maximum=5000.0)
        check_seed(seed)
        # the further runs' seeds SEED+1 ... go to the summary's extra_seeds: 64-bit integers too
        check_integer(seed, "--seed", maximum=MAX_SEED - extra_runs,
                      why=f"--extra-runs {extra_runs} takes the seeds up to SEED+{extra_runs}, 64-bit integers")
        check_vehicle_option(vehicle)
    except ValueError as exc:
        _fail(str(exc))
    try:
        # before minutes of simulation: a folder, a recording's file, the vehicle file or an
        # unwritable place is refused now (a missing folder is made at the end)
        import os

        out_n = Path(os.path.normpath(out))       # ("sub/../v.toml" is v.toml, whether sub exists or not)
        if vehicle is not None and os.path.normpath(os.path.abspath(out_n)) == os.path.normpath(
                os.path.abspath(vehicle)):
            raise OutputError(f"--out {out}: is the --vehicle file; choose another file name")
        if out_n.parent.is_dir():
            check_outputs([("--out", out_n)], inputs=[vehicle])
    except OutputError as exc:
        _fail(str(exc))
    vp, vehicle_name, (sigma_acc, sigma_gyro) = vehicle_for_run(vehicle, speed_m_s, sensor_gravity=sensor_gravity)
    t0 = time.process_time()
    q = decimation_factor(rate_hz, filter_rate_hz)
    noise = {"sigma_acc_m_s2": sigma_acc, "sigma_gyro_rad_s": sigma_gyro}
    with console.status("simulating the reference run"):
        run = simulate_run(vp, irregularity_from_psd(length_m, seed=seed), speed_m_s, length_m, rate_hz=rate_hz,
                           seed=seed + 1, **noise).decimated(q)
    extra = []
    with console.status("simulating the further reference runs"):
        for sd in range(seed + 1, seed + 1 + extra_runs):
            extra.append(simulate_run(vp, irregularity_from_psd(length_m, seed=sd), speed_m_s, length_m,
                                      rate_hz=rate_hz, seed=sd + 1, **noise).decimated(q).calibration_run())
    p0 = replace(nominal_parameters(vp, kind), sensor_gravity=sensor_gravity)
    with console.status("identifying and tuning"):
        mdl = calibrate(p0, speed_m_s, run.t_s, run.s_m, run.reference_states(kind, roll=sensor_gravity),
                        run.sensors(), extra_runs=extra)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_model(out, mdl, provenance=f"calibrated for {vehicle_name} at {speed_m_s:g} m/s, {rate_hz:g} Hz, "
                                          f"{length_m:g} m, seeds {seed}-{seed + extra_runs}")
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    jsonout.echo({"out": out, "vehicle": vehicle_name, "kind": kind, "sensor_gravity": sensor_gravity, "seed": seed, "extra_seeds": list(range(seed + 1, seed + 1 + extra_runs)),
                  "speed_m_s": speed_m_s, "length_m": length_m, "rate_hz": rate_hz, "filter_rate_hz": rate_hz / q,
                  "kx_n_m": mdl.params.kx, "cx_n_s_m": mdl.params.cx, "ky_n_m": mdl.params.ky,
                  "cy_n_s_m": mdl.params.cy, "sigma_scale": mdl.sigma_scale,
                  "innovation_rms": dict(zip(CONSISTENCY_KEYS, map(float, mdl.innovation_rms))),
                  "cpu_s": round(time.process_time() - t0, 2)})


def register(app: typer.Typer) -> None:
    """Add the ``inservice`` command group to the ``trolley`` app."""
    app.add_typer(inservice_app, name="inservice")
