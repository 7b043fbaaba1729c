"""``trolley devices``: check and record real or simulated serial instruments.

``probe`` talks GeoCOM to a total station, ``record`` records IMU / odometer / gauge into the raw
session files of FORMATS.md section 1 (plus raw byte logs and counters), ``simulate`` starts a
device twin on a pseudo-terminal and prints the port to use (docs/drivers.md).
"""
from __future__ import annotations

import json
import math
import os
import tempfile
import time
from enum import Enum
from pathlib import Path

import typer

devices_app = typer.Typer(help="Check, record and simulate the trolley's serial instruments.",
                          no_args_is_help=True)


def _err(msg: str) -> None:
    typer.echo("error: " + " ".join(str(msg).split()), err=True)


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _csv(header: list[str], cols: list) -> str:
    import numpy as np
    import pandas as pd

    frame = pd.DataFrame({h: np.asarray(c, float) for h, c in zip(header, cols)})
    return frame.to_csv(index=False, lineterminator="\n")


@devices_app.command("probe")
def probe(
    totalstation: str = typer.Option(..., "--totalstation", help="Serial port of the total station."),
    baud: int = typer.Option(19200, "--baud", help="Baud rate (9600 and 19200 are both common)."),
    crc: bool = typer.Option(False, "--crc/--no-crc", help="Use the GeoCOM CRC-16 field."),
    timeout_s: float = typer.Option(3.0, "--timeout-s", help="Reply timeout of quick calls."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object on stdout."),
) -> None:
    """Connection check, software version, ATR fine-adjust and one measurement."""
    from drivers import geocom
    from drivers.serialport import DeviceError
    from drivers.totalstation import TotalStation

    ts = TotalStation(totalstation, baudrate=baud, use_crc=crc, timeout_s=timeout_s)
    out: dict
    try:
        ts.connect()
        ver = ts.sw_version()
        ts.fine_adjust()
        m = ts.measure()
        out = {"ok": True, "E_m": m.E_m, "N_m": m.N_m, "H_m": m.H_m, "hz_rad": m.hz_rad,
               "v_rad": m.v_rad, "slope_m": m.slope_m, "rc": m.rc,
               "geocom_version": ".".join(map(str, ver))}
    except geocom.GeoComError as e:
        out = {"ok": False, "rc": e.code, "name": e.name, "error": str(e)}
    except DeviceError as e:
        out = {"ok": False, "rc": 3103, "name": geocom.code_name(3103), "error": str(e)}
    finally:
        ts.close()
    if as_json:
        typer.echo(json.dumps(out))
    elif out["ok"]:
        typer.echo(f"E={out['E_m']:.4f} N={out['N_m']:.4f} H={out['H_m']:.4f} m  "
                   f"Hz={out['hz_rad']:.6f} V={out['v_rad']:.6f} rad  SD={out['slope_m']:.4f} m  rc={out['rc']}")
    if not out["ok"]:
        _err(f"total station on {totalstation}: {out['error']}")
        raise typer.Exit(code=1)


@devices_app.command("record")
def record_cmd(
    imu: str = typer.Option(..., "--imu", help="Serial port of the IMU (NovAtel RAWIMUSXB)."),
    odometer: str | None = typer.Option(None, "--odometer", help="Serial port of the encoder counter."),
    gauge: str | None = typer.Option(None, "--gauge", help="Serial port of the gauge sensor."),
    seconds: float = typer.Option(..., "--seconds", min=0.0, help="How long to record."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    imu_axes: str = typer.Option("x,y,z", "--imu-axes", help="IMU axes to trolley FRD, e.g. 'x,-y,-z'."),
    imu_type: int | None = typer.Option(None, "--imu-type", help="IMU type for the scale table (default: from the frames)."),
    imu_rate_hz: float | None = typer.Option(None, "--imu-rate-hz", help="IMU data rate (default: the IMU type's)."),
    odometer_ppr: int = typer.Option(1024, "--odometer-ppr", help="Encoder pulses per revolution."),
    odometer_decode: int = typer.Option(4, "--odometer-decode", help="Quadrature decode 1, 2 or 4."),
    wheel_diameter_m: float = typer.Option(0.1, "--wheel-diameter-m", help="Measuring wheel diameter."),
    odometer_scale: float = typer.Option(1.0, "--odometer-scale", help="Calibrated scale factor."),
    odometer_bits: int = typer.Option(32, "--odometer-bits", help="Counter width (8, 16, 24, 32)."),
    odometer_rate_hz: float = typer.Option(100.0, "--odometer-rate-hz", min=100.0, help="Polling rate."),
) -> None:
    """Record imu.csv, odometer.csv, gauge.csv (FORMATS.md section 1), raw logs and stats.json."""
    from drivers import encoder, novatel
    from drivers.recorder import RecordConfig, record
    from drivers.serialport import DeviceError

    try:
        novatel.axis_matrix(imu_axes)
        odo = encoder.OdometerConfig(ppr=odometer_ppr, decode=odometer_decode, wheel_diameter_m=wheel_diameter_m,
                                     scale=odometer_scale, bits=odometer_bits, rate_hz=odometer_rate_hz)
        if imu_type is not None:
            novatel.imu_scale(imu_type)
    except (ValueError, KeyError) as e:
        _err(str(e).strip("'\""))
        raise typer.Exit(code=2)
    out.mkdir(parents=True, exist_ok=True)
    cfg = RecordConfig(imu_port=imu, seconds=seconds, odometer_port=odometer, gauge_port=gauge, raw_dir=out,
                       imu_axes=imu_axes, imu_type=imu_type, imu_rate_hz=imu_rate_hz, odometer=odo)
    try:
        rec = record(cfg)
    except DeviceError as e:
        _err(str(e))
        raise typer.Exit(code=2)
    except KeyError as e:
        _err(f"IMU on {imu}: {str(e).strip(chr(34))}")
        raise typer.Exit(code=2)
    stats = {k: v.as_dict() for k, v in rec.stats.items()}
    _write_atomic(out / "stats.json", json.dumps(stats, indent=2) + "\n")
    if len(rec.imu_t_s) == 0:
        _err(f"IMU on {imu}: no valid RAWIMUSXB frame in {seconds:g} s; nothing written but "
             f"{out / 'stats.json'} and the raw logs")
        raise typer.Exit(code=1)
    w, f = rec.imu_w_rad_s, rec.imu_f_m_s2
    _write_atomic(out / "imu.csv", _csv(["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2"],
                                        [rec.imu_t_s, w[:, 0], w[:, 1], w[:, 2], f[:, 0], f[:, 1], f[:, 2]]))
    if rec.odo_t_s is not None:
        _write_atomic(out / "odometer.csv", _csv(["t_s", "distance_m"], [rec.odo_t_s, rec.odo_distance_m]))
    if rec.gauge_t_s is not None:
        _write_atomic(out / "gauge.csv", _csv(["t_s", "gauge_m"], [rec.gauge_t_s, rec.gauge_m]))
    from rich.console import Console

    Console(stderr=True).print(
        f"recorded {len(rec.imu_t_s)} IMU samples"
        + (f", {len(rec.odo_t_s)} odometer reads" if rec.odo_t_s is not None else "")
        + (f", {len(rec.gauge_t_s)} gauge readings" if rec.gauge_t_s is not None else "")
        + f" into {out}", highlight=False)


class Device(str, Enum):
    imu = "imu"
    odometer = "odometer"
    gauge = "gauge"
    totalstation = "totalstation"


def _floats(s: str, n: int, name: str) -> tuple[float, ...]:
    try:
        v = tuple(float(x) for x in s.split(","))
    except ValueError:
        v = ()
    if len(v) != n:
        _err(f"{name}: need {n} comma-separated numbers, got {s!r}")
        raise typer.Exit(code=2)
    return v


@devices_app.command("simulate")
def simulate(
    device: Device = typer.Option(..., "--device", help="Which twin to start."),
    seconds: float = typer.Option(600.0, "--seconds", help="How long the twin runs."),
    link: Path | None = typer.Option(None, "--link", help="Also make this stable symlink to the port."),
    rate_hz: float = typer.Option(200.0, "--rate-hz", help="IMU / gauge data rate."),
    imu_type: int = typer.Option(26, "--imu-type", help="IMU type of the IMU twin (scale table)."),
    speed_m_s: float = typer.Option(1.0, "--speed-m-s", help="Trolley speed of the odometer twin."),
    station: str = typer.Option("0,0,0,1.5", "--station", help="Total-station twin: E0,N0,H0,Hi."),
    target: str = typer.Option("10,20,0.5", "--target", help="Total-station twin: prism E,N,H."),
    noise_angle_rad: float = typer.Option(0.0, "--noise-angle-rad"),
    noise_dist_m: float = typer.Option(0.0, "--noise-dist-m"),
    corrupt_rate: float = typer.Option(0.0, "--corrupt-rate", help="Probability per byte of corruption."),
    drop_rate: float = typer.Option(0.0, "--drop-rate", help="Probability per byte of being dropped."),
    garbage_rate: float = typer.Option(0.0, "--garbage-rate", help="Probability per write of a garbage burst."),
    seed: int = typer.Option(0, "--seed"),
) -> None:
    """Start a device twin on a pseudo-terminal; prints the port path, runs ``--seconds``."""
    import numpy as np

    from drivers import encoder
    from drivers.twins.base import Faults

    faults = Faults(corrupt_rate=corrupt_rate, drop_rate=drop_rate, garbage_rate=garbage_rate, seed=seed)
    n = max(int(seconds * rate_hz), 2)
    t = np.arange(n) / rate_hz
    if device is Device.imu:
        from drivers.twins.imu import ImuTwin

        from trolley import units

        # level and facing north at 45 deg latitude: Earth rate (cos, 0, -sin) * Omega in FRD
        lat = float(units.deg_to_rad(45.0))
        w = np.tile([units.EARTH_RATE_RAD_S * math.cos(lat), 0.0, -units.EARTH_RATE_RAD_S * math.sin(lat)], (n, 1))
        f = np.tile([0.0, 0.0, -units.STANDARD_GRAVITY_M_S2], (n, 1))
        twin = ImuTwin(t, w, f, imu_type=imu_type, rate_hz=rate_hz, faults=faults, link_path=link)
    elif device is Device.gauge:
        from drivers.twins.gauge import GaugeTwin

        twin = GaugeTwin(t, 1.435 + 0.002 * np.sin(2 * np.pi * t / 10.0), faults=faults, link_path=link)
    elif device is Device.odometer:
        from drivers.twins.odometer import OdometerTwin

        to = np.arange(max(int(seconds * 1000), 2)) / 1000.0
        twin = OdometerTwin(to, speed_m_s * to, encoder.OdometerConfig(), mode="time", faults=faults, link_path=link)
    else:
        from drivers.twins.totalstation import TotalStationTwin

        twin = TotalStationTwin(_floats(station, 4, "--station"), _floats(target, 3, "--target"),
                                noise_angle_rad, noise_dist_m, faults=faults, link_path=link, seed=seed)
    typer.echo(twin.port)
    import sys

    sys.stdout.flush()
    try:
        twin.start(wait_client_s=seconds)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        twin.stop()


def register(app: typer.Typer) -> None:
    """Add the ``devices`` command group."""
    app.add_typer(devices_app, name="devices")
