"""``trolley inservice simulate``: a synthetic in-service recording (docs/inservice.md) plus its truth;
``trolley inservice vehicle``: the default vehicle as a vehicle file, and the reading of ``--vehicle``
that simulate and calibrate share (:func:`vehicle_for_run`).

Runs the full-vehicle truth simulator (``trolley.inservice.vehicle``) over PSD irregularities
(and/or a harmonic alignment, the resonance case of Munoz 2021 Sec. V-E) and writes
``OUT/recording/`` (inservice.toml + sensors.csv) and ``OUT/truth.csv`` outside the recording, all
or none of them; an existing OUT is written again only if this command made it (its marker), so
a recording is never replaced.
Command-line values are at the edge: curvature positive for a RIGHT turn (as in the files),
harmonic amplitude in mm. A JSON summary goes to stdout, errors to stderr (exit 2).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console

from survey import jsonout
from survey.atomicwrite import OutputError, all_or_nothing, guard_overwrite, write_marker
from survey.commands.options import JsonAlways
from survey.limits import check_file_option, check_finite, check_seed

console = Console(stderr=True)


def _fail(msg: str) -> None:
    """One line on stderr, exit 2. The message is printed as text, not markup: a path or a value
    with brackets ("data/[old]/rec", "[x, y, z]") must appear as written."""
    from rich.text import Text

    console.print(Text.assemble(("error:", "red"), " ", msg), highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


VehicleOption = Annotated[Optional[Path], typer.Option(
    "--vehicle", help="vehicle file (`trolley inservice vehicle --out FILE` writes one to edit; docs/inservice.md, "
                      "\"Your vehicle\"); default: the Manchester benchmark vehicle with the paper's sensor noise")]


def check_vehicle_option(vehicle: Optional[Path]) -> None:
    """Refuse a missing file or a folder given to --vehicle, naming the option (ValueError): the
    reader said "nosuch.toml: file not found in ." and "/tmp: is a folder", without it."""
    from survey.inservice_vehicle import VEHICLE_MADE_BY

    check_file_option(vehicle, "--vehicle", "a vehicle file", "vehicle.toml", VEHICLE_MADE_BY)


def vehicle_for_run(vehicle: Optional[Path], speed_m_s: float, **conditions):
    """The truth simulator's vehicle for a run: the vehicle file's (or the default one) with the run
    conditions (``conicity_factor``, ``creep_factor``, ``sensor_gravity``), and its sensor noise
    sigmas. Exits 2 on a bad file, and on a vehicle that hunts at ``speed_m_s`` (its centred running
    is unstable: the run would be a flange-bounded limit cycle, not the response to the track)."""
    from dataclasses import replace

    from survey.inservice_vehicle import VehicleFileError, read_vehicle
    from trolley.inservice.vehicle import (DEFAULT_VEHICLE_NAME, HUNTING_TOLERANCE_1_S, MIN_STEP_S, SIGMA_ACC_M_S2,
                                           SIGMA_GYRO_RAD_S, VehicleParameters, integration_step_s,
                                           largest_growth_rate, linearised_eigenvalues)

    if vehicle is None:
        params, name, sigmas = VehicleParameters(), DEFAULT_VEHICLE_NAME, (SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S)
    else:
        try:
            vf = read_vehicle(vehicle)
        except VehicleFileError as exc:
            _fail(str(exc))
        params, name, sigmas = vf.params, vf.name, (vf.sigma_acc_m_s2, vf.sigma_gyro_rad_s)
        if vf.defaults:
            console.print(f"note: {vehicle} leaves {len(vf.defaults)} values at the {DEFAULT_VEHICLE_NAME}'s: "
                          + ", ".join(vf.defaults), highlight=False, markup=False, soft_wrap=True)
    params = replace(params, **conditions)
    ev = linearised_eigenvalues(params, speed_m_s)
    rate = largest_growth_rate(params, speed_m_s, ev)
    if rate > HUNTING_TOLERANCE_1_S:
        _fail(f"{vehicle or name}: the vehicle hunts at {speed_m_s:g} m/s (its linearised lateral motion grows at "
              f"{rate:.3g} 1/s): a lower speed, or more yaw stiffness or conicity damping in the vehicle")
    step = integration_step_s(params, speed_m_s, 200.0, ev)
    if step < MIN_STEP_S:
        _fail(f"{vehicle or name}: the vehicle's fastest mode needs an integration step of {step:.3g} s, below "
              f"{MIN_STEP_S:g} s: stiffer or lighter than any rail vehicle (check the units)")
    return params, name, sigmas


def vehicle_cmd(
    out: Annotated[Path, typer.Option("--out", help="vehicle file to write (TOML)")],
    json_output: JsonAlways = False,
) -> None:
    """Write a vehicle file to edit for your vehicle.

    It holds the default vehicle (the Manchester benchmark vehicle) and every key; `simulate` and
    `calibrate` read it with --vehicle (docs/inservice.md, "Your vehicle")."""
    from survey.atomicwrite import check_outputs
    from survey.inservice_vehicle import write_vehicle
    from trolley.inservice.vehicle import DEFAULT_VEHICLE_NAME, SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S, VehicleParameters

    from survey.atomicwrite import enclosing_raw_folder

    try:
        check_outputs([("--out", out)])
        if out.exists() or out.is_symlink():
            raise OutputError(f"--out {out}: exists; a vehicle file is not replaced, choose another name")
        inside = enclosing_raw_folder(out)
        if inside is not None:
            raise OutputError(f"--out {out}: is inside the recording {inside}; choose a place outside it")
        write_vehicle(out, VehicleParameters(), DEFAULT_VEHICLE_NAME, SIGMA_ACC_M_S2, SIGMA_GYRO_RAD_S)
    except OutputError as exc:
        _fail(str(exc))
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    jsonout.echo({"out": str(out), "vehicle": DEFAULT_VEHICLE_NAME})


def simulate_cmd(
    out: Annotated[Path, typer.Option("--out", help="output folder: OUT/recording/ and OUT/truth.csv")],
    speed_m_s: Annotated[float, typer.Option("--speed-m-s", help="constant speed, m/s (2-60)")] = 20.0,
    length_m: Annotated[float, typer.Option("--length-m", help="recorded length, m (10-20000)")] = 400.0,
    seed: Annotated[int, typer.Option(help="seed of the irregularities and the sensor noise")] = 0,
    curvature_1_m: Annotated[float, typer.Option(
        "--curvature-1-m", help="constant design curvature, 1/m, positive = right turn (-0.01 to 0.01)")] = 0.0,
    conicity_factor: Annotated[float, typer.Option(
        "--conicity-factor", help="multiplies the truth's conicity (0.9: -10 %; 0.1-5)")] = 1.0,
    creep_factor: Annotated[float, typer.Option(
        "--creep-factor", help="multiplies the truth's Kalker coefficients (0.5: 50 %; 0.05-5)")] = 1.0,
    no_noise: Annotated[bool, typer.Option("--no-noise", help="no sensor noise")] = False,
    no_vertical: Annotated[bool, typer.Option("--no-vertical", help="no vertical irregularity")] = False,
    no_random_lateral: Annotated[bool, typer.Option(
        "--no-random-lateral", help="no random alignment (with a harmonic: Munoz 2021 Case 2)")] = False,
    harmonic_wavelength_m: Annotated[Optional[float], typer.Option(
        "--harmonic-wavelength-m", help="add a harmonic alignment of this wavelength, m (1-1000)")] = None,
    harmonic_amplitude_mm: Annotated[float, typer.Option(
        "--harmonic-amplitude-mm", help="its amplitude, mm (0-20)")] = 1.0,
    resonance: Annotated[bool, typer.Option(
        "--resonance", help="harmonic at the wavelength of the first lateral bogie mode at this speed")] = False,
    rate_hz: Annotated[float, typer.Option("--rate-hz", help="sensor rate, Hz (20-2000)")] = 200.0,
    sensor_gravity: Annotated[bool, typer.Option(
        "--sensor-gravity", help="accelerometers also sense g x their roll (not in the paper)")] = False,
    vehicle: VehicleOption = None,
    json_output: JsonAlways = False,
) -> None:
    """Write a synthetic in-service recording (wheelset and bogie frame inertial sensors) plus truth.csv."""
    from survey import inservice_io
    from trolley import units
    from trolley.inservice import irregularity as irr
    from trolley.inservice.vehicle import first_lateral_mode, simulate_run

    try:
        # the ranges here, not as typer min/max: nan got "Input should be less than or equal to 60"
        check_finite(speed_m_s, "--speed-m-s", minimum=2.0, maximum=60.0)
        check_finite(length_m, "--length-m", minimum=10.0, maximum=20000.0)
        check_seed(seed)
        check_finite(curvature_1_m, "--curvature-1-m", minimum=-0.01, maximum=0.01)
        check_finite(conicity_factor, "--conicity-factor", minimum=0.1, maximum=5.0)
        check_finite(creep_factor, "--creep-factor", minimum=0.05, maximum=5.0)
        check_finite(harmonic_wavelength_m, "--harmonic-wavelength-m", minimum=1.0, maximum=1000.0)
        check_finite(harmonic_amplitude_mm, "--harmonic-amplitude-mm", minimum=0.0, maximum=20.0)
        check_finite(rate_hz, "--rate-hz", minimum=20.0, maximum=2000.0)
        check_vehicle_option(vehicle)
    except ValueError as exc:
        _fail(str(exc))
    if harmonic_wavelength_m is not None and resonance:
        _fail("give --harmonic-wavelength-m or --resonance, not both")
    try:
        # a recording is raw data: only a folder this command made may be written again
        guard_overwrite(out, "inservice simulate", force=False, reuse_own=True)
    except OutputError as exc:
        _fail(str(exc))
    params, vehicle_name, (sigma_acc, sigma_gyro) = vehicle_for_run(
        vehicle, speed_m_s, conicity_factor=conicity_factor, creep_factor=creep_factor, sensor_gravity=sensor_gravity)
    try:
        mode = first_lateral_mode(params, speed_m_s)
    except ValueError:
        mode = None     # a vehicle file whose bogies have no oscillatory lateral mode at this speed
    if resonance and mode is None:
        _fail(f"--resonance: the vehicle ({vehicle_name}) has no oscillatory lateral bogie mode at {speed_m_s:g} m/s")
    wavelength = mode.wavelength_m if resonance else harmonic_wavelength_m
    if no_random_lateral and wavelength is None:
        _fail("--no-random-lateral needs a harmonic (--harmonic-wavelength-m or --resonance)")
    kappa = -curvature_1_m  # right-turn positive at the edge -> left positive inside
    t0 = time.process_time()
    track = irr.irregularity_from_psd(length_m, seed=seed, lateral_scale=0.0 if no_random_lateral else 1.0,
                                      vertical_scale=0.0 if no_vertical else 1.0)
    if wavelength is not None:
        track = track.plus(irr.harmonic_irregularity(length_m, wavelength, units.mm_to_m(harmonic_amplitude_mm)))
    with console.status("simulating the vehicle"):
        run = simulate_run(params, track, speed_m_s, length_m, rate_hz=rate_hz, sensor_noise=not no_noise,
                           seed=seed + 1, curvature_1_m=kappa, sigma_acc_m_s2=sigma_acc, sigma_gyro_rad_s=sigma_gyro)
    cpu = time.process_time() - t0
    try:
        out.mkdir(parents=True, exist_ok=True)
        with all_or_nothing():
            inservice_io.write_recording(out / "recording", inservice_io.recording_from_run(
                run, params, vehicle_name=vehicle_name))
            inservice_io.write_truth(out / "truth.csv", run.s_m, run.alignment_m, run.vertical_m,
                                     run.curvature_1_m)
        write_marker(out, "inservice simulate")
    except OSError as exc:
        _fail(f"{out}: cannot write ({exc})")
    import numpy as np
    jsonout.echo({
        "out": str(out), "vehicle": vehicle_name, "seed": seed, "speed_m_s": speed_m_s, "length_m": length_m, "samples": int(len(run.t_s)),
        "curvature_1_m": curvature_1_m, "conicity_factor": conicity_factor, "creep_factor": creep_factor,
        "noise": not no_noise, "vertical": not no_vertical, "random_lateral": not no_random_lateral,
        "harmonic_wavelength_m": wavelength, "harmonic_amplitude_mm": harmonic_amplitude_mm if wavelength else None,
        "first_lateral_mode_hz": mode.frequency_hz if mode else None,
        "first_lateral_mode_wavelength_m": mode.wavelength_m if mode else None,
        "alignment_rms_mm": float(units.m_to_mm(np.sqrt(np.mean(run.alignment_m ** 2)))),
        "max_wheel_rail_shift_mm": float(units.m_to_mm(run.max_shift_m)),
        "step_s": run.step_s, "cpu_s": round(cpu, 2)})
