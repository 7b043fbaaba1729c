"""``trolley devices``: check and record real or simulated serial instruments.

``probe`` talks GeoCOM to a total station, ``record`` records IMU / odometer / gauge into the raw
session files of FORMATS.md section 1 (plus raw byte logs and counters), ``simulate`` starts the
device twins on pseudo-terminals and writes the devices file naming their ports (docs/drivers.md).
"""
from __future__ import annotations

import json
import math
import time
from contextlib import contextmanager
from pathlib import Path

import typer

from survey import jsonout
from survey.atomicwrite import MARKER_NAME, OutputError, guard_overwrite, write_marker, write_text_atomic
from survey.commands.options import Device, JsonAlways, JsonFlag, old_name, renamed
from survey.limits import check_finite, check_integer, check_seed

devices_app = typer.Typer(help="Check, record and simulate the trolley's serial instruments.",
                          no_args_is_help=True, rich_markup_mode=None)


#: the longest recording or twin run, s: a day (a longer survey is several recordings);
#: --seconds 1e300 reached threading's wait() and overflowed its timeout after the ports were opened
MAX_SECONDS = 86400.0
#: the fastest IMU data rate, Hz: ten times the fastest type of the scale table (200 Hz);
#: --imu-rate-hz 1e9 on the twins allocated until the memory ran out
MAX_IMU_RATE_HZ = 2000.0
#: the fastest gauge sensor and odometer polling rates, Hz (--gauge-rate-hz 1e9 as the IMU's)
MAX_SENSOR_RATE_HZ = 1000.0
#: the fastest synthetic trolley, m/s (the accuracy budget's range)
MAX_SPEED_M_S = 30.0
#: the line speeds of a serial port, baud: pyserial's standard rates (serial.SerialBase.BAUDRATES)
#: and Linux's termios span 50 to 4,000,000; 0 is termios' B0, which hangs the line up, and --baud
#: 10^12 reached pyserial's ioctl and overflowed it ("signed integer is greater than maximum")
MIN_BAUD = 50
MAX_BAUD = 4_000_000
BAUD_WHY = f"the serial line speeds are {MIN_BAUD} to {MAX_BAUD} baud"
#: the finest rotary encoders count about 10^5 to 10^6 pulses per revolution; --odometer-ppr 10^12
#: was taken, a count then 8e-14 m of the 0.1 m wheel, and a 32-bit counter wrapped every 0.34 mm
MAX_ODOMETER_PPR = 1_000_000


def _err(msg: str) -> None:
    typer.echo("error: " + " ".join(str(msg).split()), err=True)


@contextmanager
def _option_values():
    """Around the survey.limits.check_finite calls of a command: a ValueError is the one-line
    error, exit 2.

    The ranges are checked there, not as typer ``min=``/``max=``: typer's range check answered
    nan with "Input should be greater than or equal to 0", and let inf through (``devices
    simulate --seconds inf`` ran until killed)."""
    try:
        yield
    except ValueError as e:
        _err(str(e))
        raise typer.Exit(code=2)


def _csv(header: list[str], cols: list) -> str:
    import numpy as np
    import pandas as pd

    frame = pd.DataFrame({h: np.asarray(c, float) for h, c in zip(header, cols)})
    return frame.to_csv(index=False, lineterminator="\n")


@devices_app.command("probe")
def probe(
    totalstation: str | None = typer.Option(None, "--totalstation-port", help="Serial port of the total station "
                                                                          "(required)."),
    baud: int = typer.Option(19200, "--baud", help=f"Baud rate (9600 and 19200 are both common; "
                                                    f"{MIN_BAUD}-{MAX_BAUD})."),
    crc: bool | None = typer.Option(None, "--crc/--no-crc",
                                    help="GeoCOM CRC-16 field on/off (default: on if the instrument answers with it)."),
    timeout_s: float = typer.Option(3.0, "--timeout-s", help="Reply timeout of quick calls, s (> 0, up to 600)."),
    as_json: JsonFlag = False,
    totalstation_old: str | None = typer.Option(None, "--totalstation", hidden=True,
                                                help=old_name("--totalstation-port")),
) -> None:
    """Connection check, software version, ATR fine-adjust and one measurement."""
    with _option_values():
        check_finite(timeout_s, "--timeout-s", positive=True, maximum=600.0)
        check_integer(baud, "--baud", minimum=MIN_BAUD, maximum=MAX_BAUD, why=BAUD_WHY)
    totalstation = renamed(totalstation, totalstation_old, "--totalstation-port", "--totalstation")
    if totalstation is None:
        raise typer.BadParameter("the serial port of the total station is required",
                                 param_hint="--totalstation-port")
    from drivers import geocom
    from drivers.serialport import DeviceError
    from drivers.totalstation import TotalStation

    ts = TotalStation(totalstation, baudrate=baud, use_crc=bool(crc), timeout_s=timeout_s)
    out: dict
    try:
        ts.connect()
        if crc is None:
            ts.detect_crc()
        ver = ts.sw_version()
        ts.fine_adjust()
        m = ts.measure()
        out = {"ok": True, "E_m": m.E_m, "N_m": m.N_m, "H_m": m.H_m, "hz_rad": m.hz_rad,
               "v_rad": m.v_rad, "slope_m": m.slope_m, "rc": m.rc,
               "geocom_version": ".".join(map(str, ver)), "crc": ts.use_crc,
               "coord_time_ms": m.coord_time_ms}
    except geocom.GeoComError as e:
        out = {"ok": False, "rc": e.code, "name": e.name, "error": str(e)}
    except DeviceError as e:
        out = {"ok": False, "rc": 3103, "name": geocom.code_name(3103), "error": str(e)}
    finally:
        ts.close()
    if as_json:
        jsonout.echo(out)
    elif out["ok"]:
        typer.echo(f"E={out['E_m']:.4f} N={out['N_m']:.4f} H={out['H_m']:.4f} m  "
                   f"Hz={out['hz_rad']:.6f} V={out['v_rad']:.6f} rad  SD={out['slope_m']:.4f} m  rc={out['rc']}")
    if not out["ok"]:
        _err(f"total station on {totalstation}: {out['error']}")
        raise typer.Exit(code=1)


@devices_app.command("record")
def record_cmd(
    imu: str | None = typer.Option(None, "--imu-port", help="Serial port of the IMU (NovAtel RAWIMUSXB; "
                                                             "required)."),
    odometer: str | None = typer.Option(None, "--odometer-port", help="Serial port of the encoder counter."),
    gauge: str | None = typer.Option(None, "--gauge-port", help="Serial port of the gauge sensor."),
    seconds: float = typer.Option(..., "--seconds", help="How long to record, s (>= 0)."),
    out: Path = typer.Option(..., "--out", help="Output folder."),
    imu_axes: str = typer.Option("x,y,z", "--imu-axes", help="IMU axes to trolley FRD, e.g. 'x,-y,-z'."),
    imu_type: int | None = typer.Option(None, "--imu-type", help="IMU type for the scale table (default: from the frames)."),
    imu_rate_hz: float | None = typer.Option(None, "--imu-rate-hz", help="IMU data rate (default: inferred from the first 21 frames; the IMU type's with fewer)."),
    odometer_ppr: int = typer.Option(1024, "--odometer-ppr", help=f"Encoder pulses per revolution "
                                                                  f"(1-{MAX_ODOMETER_PPR})."),
    odometer_decode: int = typer.Option(4, "--odometer-decode", help="Quadrature decode 1, 2 or 4."),
    wheel_diameter_m: float = typer.Option(0.1, "--wheel-diameter-m", help="Measuring wheel diameter."),
    odometer_scale: float = typer.Option(1.0, "--odometer-scale", help="Calibrated scale factor."),
    odometer_bits: int = typer.Option(32, "--odometer-bits", help="Counter width (8, 16, 24, 32)."),
    odometer_rate_hz: float = typer.Option(100.0, "--odometer-rate-hz", help="Polling rate (>= 100 Hz)."),
    imu_baud: int = typer.Option(460800, "--imu-baud", help=f"IMU line speed ({MIN_BAUD}-{MAX_BAUD})."),
    odometer_baud: int = typer.Option(115200, "--odometer-baud", help=f"Counter module line speed "
                                                                     f"({MIN_BAUD}-{MAX_BAUD})."),
    gauge_baud: int = typer.Option(115200, "--gauge-baud", help=f"Gauge sensor line speed ({MIN_BAUD}-{MAX_BAUD})."),
    as_json: JsonFlag = False,
    imu_old: str | None = typer.Option(None, "--imu", hidden=True, help=old_name("--imu-port")),
    odometer_old: str | None = typer.Option(None, "--odometer", hidden=True, help=old_name("--odometer-port")),
    gauge_old: str | None = typer.Option(None, "--gauge", hidden=True, help=old_name("--gauge-port")),
) -> None:
    """Record imu.csv, odometer.csv, gauge.csv (FORMATS.md section 1), raw logs and stats.json."""
    from drivers.encoder import FIELD_WIDTH

    with _option_values():
        check_finite(seconds, "--seconds", minimum=0.0, maximum=MAX_SECONDS, why="a day")
        check_finite(imu_rate_hz, "--imu-rate-hz", positive=True, maximum=MAX_IMU_RATE_HZ)
        check_finite(wheel_diameter_m, "--wheel-diameter-m", positive=True, maximum=2.0,
                     why="a measuring wheel")
        check_finite(odometer_scale, "--odometer-scale", minimum=0.5, maximum=2.0,
                     why="a calibrated scale factor is close to 1")
        check_finite(odometer_rate_hz, "--odometer-rate-hz", minimum=100.0, maximum=MAX_SENSOR_RATE_HZ)
        check_integer(odometer_ppr, "--odometer-ppr", minimum=1, maximum=MAX_ODOMETER_PPR,
                      why="the finest rotary encoders count about 10^6 pulses per revolution")
        # drivers.encoder.OdometerConfig refuses these too, but naming no option
        if odometer_decode not in (1, 2, 4):
            raise ValueError(f"--odometer-decode: must be 1, 2 or 4, got {odometer_decode}")
        if odometer_bits not in FIELD_WIDTH:
            *widths, last = sorted(FIELD_WIDTH)
            raise ValueError(f"--odometer-bits: must be {', '.join(map(str, widths))} or {last}, got {odometer_bits}")
        for value, option in ((imu_baud, "--imu-baud"), (odometer_baud, "--odometer-baud"),
                              (gauge_baud, "--gauge-baud")):
            check_integer(value, option, minimum=MIN_BAUD, maximum=MAX_BAUD, why=BAUD_WHY)
    imu = renamed(imu, imu_old, "--imu-port", "--imu")
    odometer = renamed(odometer, odometer_old, "--odometer-port", "--odometer")
    gauge = renamed(gauge, gauge_old, "--gauge-port", "--gauge")
    if imu is None:
        raise typer.BadParameter("the serial port of the IMU is required", param_hint="--imu-port")
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
    try:
        guard_overwrite(out, "devices record", force=False, reuse_own=True)
    except OutputError as e:
        _err(str(e))
        raise typer.Exit(code=2)
    made_here = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out, "devices record")
    cfg = RecordConfig(imu_port=imu, seconds=seconds, odometer_port=odometer, gauge_port=gauge, raw_dir=out,
                       imu_axes=imu_axes, imu_type=imu_type, imu_rate_hz=imu_rate_hz, odometer=odo,
                       imu_baud=imu_baud, odometer_baud=odometer_baud, gauge_baud=gauge_baud)
    try:
        rec = record(cfg)
    except (DeviceError, novatel.UnknownImuType, encoder.CounterWidthMismatch) as e:
        if made_here:
            _remove_if_nothing_recorded(out)
        _err(f"IMU on {imu}: {e}" if isinstance(e, novatel.UnknownImuType) else str(e))
        raise typer.Exit(code=2)
    stats = {k: v.as_dict() for k, v in rec.stats.items()}
    write_text_atomic(out / "stats.json", json.dumps(stats, indent=2) + "\n")
    if len(rec.imu_t_s) == 0:
        _err(f"IMU on {imu}: no valid RAWIMUSXB frame in {seconds:g} s; nothing written but "
             f"{out / 'stats.json'} and the raw logs")
        raise typer.Exit(code=1)
    w, f = rec.imu_w_rad_s, rec.imu_f_m_s2
    write_text_atomic(out / "imu.csv", _csv(["t_s", "wx_rad_s", "wy_rad_s", "wz_rad_s", "fx_m_s2", "fy_m_s2", "fz_m_s2"],
                                        [rec.imu_t_s, w[:, 0], w[:, 1], w[:, 2], f[:, 0], f[:, 1], f[:, 2]]))
    if rec.odo_t_s is not None:
        write_text_atomic(out / "odometer.csv", _csv(["t_s", "distance_m"], [rec.odo_t_s, rec.odo_distance_m]))
    if rec.gauge_t_s is not None:
        write_text_atomic(out / "gauge.csv", _csv(["t_s", "gauge_m"], [rec.gauge_t_s, rec.gauge_m]))
    from rich.console import Console

    if as_json:
        jsonout.echo({"out": out, "imu_samples": len(rec.imu_t_s),
                      "odometer_reads": None if rec.odo_t_s is None else len(rec.odo_t_s),
                      "gauge_readings": None if rec.gauge_t_s is None else len(rec.gauge_t_s), "stats": stats})
    Console(stderr=True).print(
        f"recorded {len(rec.imu_t_s)} IMU samples"
        + (f", {len(rec.odo_t_s)} odometer reads" if rec.odo_t_s is not None else "")
        + (f", {len(rec.gauge_t_s)} gauge readings" if rec.gauge_t_s is not None else "")
        + f" into {out}", highlight=False, markup=False)


def _remove_if_nothing_recorded(out: Path) -> None:
    """Remove a recording folder this run made when the devices failed before any byte came: only
    the marker and raw logs without a record in them (a port that does not exist). A folder with
    any recorded byte is kept: raw data are never deleted."""
    import shutil

    from drivers.rawlog import read_rawlog

    for p in out.iterdir():
        if p.name == MARKER_NAME:
            continue
        if not (p.is_file() and p.suffix == ".rawlog"):
            return
        try:
            if next(iter(read_rawlog(p)), None) is not None:
                return
        except (OSError, ValueError):
            return
    shutil.rmtree(out)


def _floats(s: str, n: int, name: str) -> tuple[float, ...]:
    try:
        v = tuple(float(x) for x in s.split(","))
    except ValueError:
        v = ()
    if len(v) != n:
        _err(f"{name}: need {n} comma-separated numbers, got {s!r}")
        raise typer.Exit(code=2)
    with _option_values():
        for x in v:
            check_finite(x, name)
    return v


def _session_feed(folder: Path, station: str | None):
    """Twin feed from a raw session folder (FORMATS.md section 1)."""
    import numpy as np

    from drivers.twins.fleet import FleetFeed, station_beside
    from survey.sessionio import SessionFormatError, read_session

    try:
        s = read_session(folder)
    except SessionFormatError as e:
        _err(f"--session-dir: {e}")     # e names the file inside the folder (folder/imu.csv: row ...)
        raise typer.Exit(code=2)
    enh = np.asarray(s.fixes.enh_m, float)
    st = _floats(station, 4, "--station") if station else station_beside(enh)
    return FleetFeed(s.imu_t_s, s.imu_w_rad_s, s.imu_f_m_s2, s.odo_t_s, s.odo_distance_m,
                     s.gauge_t_s, s.gauge_m, np.asarray(s.fixes.t_s, float), enh, st, repeat=False)


@devices_app.command("simulate")
def simulate(
    out: Path | None = typer.Option(None, "--out", help="Write the devices file (PORTS.json) here."),
    session_dir: Path | None = typer.Option(None, "--session-dir", help="Feed the twins from this raw session folder."),
    session_old: Path | None = typer.Option(None, "--session", hidden=True, help=old_name("--session-dir")),
    device: list[Device] = typer.Option(list(Device), "--device",
                                        help="Twin to start (repeat the option; default: all four)."),
    seconds: float | None = typer.Option(None, "--seconds",
                                         help="Stop after this long, s (>= 0; default: run until interrupted)."),
    link_dir: Path | None = typer.Option(None, "--link-dir", help="Also make stable symlinks DIR/<device>."),
    imu_rate_hz: float = typer.Option(200.0, "--imu-rate-hz", help="Synthetic IMU data rate (>= 1 Hz)."),
    gauge_rate_hz: float = typer.Option(50.0, "--gauge-rate-hz", help="Synthetic gauge rate (>= 1 Hz)."),
    imu_type: int = typer.Option(26, "--imu-type", help="IMU type of the IMU twin (scale table)."),
    speed_m_s: float = typer.Option(1.0, "--speed-m-s", help="Synthetic trolley speed (odometer twin)."),
    station: str | None = typer.Option(None, "--station", help="Total station E0,N0,H0,Hi "
                                       "(default 0,0,0,1.5; with --session-dir: beside the fixes)."),
    target: str = typer.Option("10,20,0.5", "--target", help="Synthetic prism E,N,H."),
    noise_angle_rad: float = typer.Option(0.0, "--noise-angle-rad", help="Total station angle noise, 1-sigma (>= 0)."),
    noise_dist_m: float = typer.Option(0.0, "--noise-dist-m", help="Total station distance noise, 1-sigma (>= 0)."),
    corrupt_rate: float = typer.Option(0.0, "--corrupt-rate", help="Per byte: corrupted (0-1)."),
    drop_rate: float = typer.Option(0.0, "--drop-rate", help="Per byte: dropped (0-1)."),
    garbage_rate: float = typer.Option(0.0, "--garbage-rate", help="Per write: garbage burst (0-1)."),
    delay_rate: float = typer.Option(0.0, "--delay-rate", help="Per reply: late (odometer, total station; 0-1)."),
    delay_s: float = typer.Option(0.5, "--delay-s", help="How late a delayed reply is, s (>= 0)."),
    missing_rate: float = typer.Option(0.0, "--missing-rate", help="Per reply: never sent (0-1)."),
    fault_device: list[Device] = typer.Option(list(Device), "--fault-device",
                                              help="Devices the faults apply to (repeat; default: all)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the faults' random draws."),
    as_json: JsonAlways = False,
) -> None:
    """Start the device twins on pseudo-terminals, write which port each listens on, run until
    interrupted (SIGINT/SIGTERM: ptys closed, the devices file removed, exit code 0)."""
    with _option_values():
        check_finite(seconds, "--seconds", minimum=0.0, maximum=MAX_SECONDS, why="a day; leave it out to run "
                                                                                "until interrupted")
        check_finite(imu_rate_hz, "--imu-rate-hz", minimum=1.0, maximum=MAX_IMU_RATE_HZ)
        check_finite(gauge_rate_hz, "--gauge-rate-hz", minimum=1.0, maximum=MAX_SENSOR_RATE_HZ)
        check_finite(speed_m_s, "--speed-m-s", minimum=-MAX_SPEED_M_S, maximum=MAX_SPEED_M_S)
        # a 1-sigma noise of a total station: beyond these a reading is no measurement
        check_finite(noise_angle_rad, "--noise-angle-rad", minimum=0.0, maximum=0.01)
        check_finite(noise_dist_m, "--noise-dist-m", minimum=0.0, maximum=1.0)
        for value, option in ((corrupt_rate, "--corrupt-rate"), (drop_rate, "--drop-rate"),
                              (garbage_rate, "--garbage-rate"), (delay_rate, "--delay-rate"),
                              (missing_rate, "--missing-rate")):
            check_finite(value, option, minimum=0.0, maximum=1.0)
        check_finite(delay_s, "--delay-s", minimum=0.0, maximum=600.0,
                     why="the longest reply timeout; a reply never sent is --missing-rate")
        check_seed(seed)
    import signal
    import threading

    # --session names a session in `project` and `survey`; here it is a folder (--session-dir)
    session = renamed(session_dir, session_old, "--session-dir", "--session")

    from drivers.twins.base import Faults
    from drivers.twins.fleet import Fleet, FleetConfig, synthetic_feed

    device = [d.value for d in device]
    fault_device = [d.value for d in fault_device]
    if out is not None and not out.parent.is_dir():
        _err(f"--out {out}: folder {out.parent} does not exist")
        raise typer.Exit(code=2)
    if link_dir is not None and not link_dir.is_dir():
        _err(f"--link-dir {link_dir}: not a folder")
        raise typer.Exit(code=2)
    if session is not None:
        feed = _session_feed(session, station)
    else:
        feed = synthetic_feed(imu_rate_hz, gauge_rate_hz, speed_m_s,
                              _floats(station or "0,0,0,1.5", 4, "--station"), _floats(target, 3, "--target"))
    cfg = FleetConfig(imu_type=imu_type, noise_angle_rad=noise_angle_rad, noise_dist_m=noise_dist_m,
                      faults=Faults(corrupt_rate=corrupt_rate, drop_rate=drop_rate, garbage_rate=garbage_rate,
                                    delay_rate=delay_rate, delay_s=delay_s, missing_rate=missing_rate, seed=seed),
                      fault_devices=tuple(fault_device), link_dir=str(link_dir) if link_dir else None)
    try:
        fleet = Fleet(feed, cfg, tuple(device))
    except (ValueError, KeyError) as e:
        _err(str(e).strip("'\""))
        raise typer.Exit(code=2)
    stop = threading.Event()

    def on_signal(signum, frame) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    wrote = False
    try:
        ports = fleet.ports_json()
        if out is not None:
            write_text_atomic(out, json.dumps(ports, indent=2) + "\n")
            wrote = True
        jsonout.echo(ports)
        import sys

        sys.stdout.flush()
        fleet.start()
        end = time.monotonic() + seconds if seconds is not None else math.inf
        while not stop.wait(0.05) and time.monotonic() < end:
            fleet.tick(time.monotonic())
    finally:
        fleet.stop()
        if wrote and out.exists():
            out.unlink()  # the ports it names are gone: a stale file would mislead `survey start`


def register(app: typer.Typer) -> None:
    """Add the ``devices`` command group."""
    app.add_typer(devices_app, name="devices")
