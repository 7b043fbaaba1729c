"""The field survey session: device check, free station, static alignment, stop-and-go loop, end.

One loop drives the session, ticking about 20 times a wall-clock second: it moves the decoded
samples into the store (through :class:`survey.session.acquisition.Acquisition`), follows the
trolley (standing or moving, from the odometer), runs the static alignment, refreshes the live
screen, and carries out the crew's actions, which come from the keyboard or from a script
(:mod:`survey.session.script`). Everything the crew decides is written to the project store at
once: fixes with their decisions, stops, notes, pause/resume/turn events and the script position,
so ``trolley survey resume`` rebuilds the state from the store alone (:meth:`FieldSession.run`
with ``resume=True``).

See ``docs/field_session.md``.
"""
from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from survey.session.acquisition import Acquisition, TimeBase
from survey.session.errors import SessionAbort
from survey.session.interval import tolerance_set_name
from survey.session.livefilter import LiveFiltering, interval_sigma_mm, predicted_sigma_mm
from survey.session.stationsetup import StationSetupSteps
from survey.session.screen import KEYS_HELP, ScreenState, render
from survey.session.script import Action
from survey.store import FixRecord, NoteRecord, ProjectStore, RecordWriter, SessionEvent, StopRecord
from rich.markup import escape

#: the trolley stands when the odometer moved less than this over ``STAND_WINDOW_S``
STAND_TOLERANCE_M = 0.002
STAND_WINDOW_S = 1.0
#: past the static alignment's end, the data an interactive simulated world sends before it waits for
#: the crew at the first stop: a sample of every stream (the odometer's period is 0.01 s)
ALIGNMENT_DATA_MARGIN_S = 0.05
#: an interactive simulated world stays this long (wall-clock) at a stop after the crew's fix there:
#: time for ``s`` (a station change, whose overlap check measures this stop again), ``u`` or ``n``
#: before the trolley moves on; at 40x it left in the next tick, and a station change found it moving
CREW_LINGER_S = 2.0
TICK_S = 0.05
#: an interactive simulated world resumed at a stop's end stands there on while the data it sends
#: (``STOP_GRACE_S`` more at each resume) take the trolley at most this far from the stop: half
#: ``STAND_TOLERANCE_M``, so the session still sees it standing
HELD_MOVE_M = 0.5 * STAND_TOLERANCE_M
#: a scripted crew looks at the simulated world at least every this many simulated seconds
SIM_STEP_S = 2.0
#: reason stored with a fix that failed the innovation test, until the crew decides
SUSPICIOUS = "innovation test failed"
#: the decision on a suspicious fix the crew accepted anyway (the final processing keeps it)
CREW_ACCEPTED = "accepted by the crew despite the innovation test"
#: how long the device check retries opening a port (a USB adapter being plugged in)
OPEN_TIMEOUT_S = 2.0


@dataclass
class SessionConfig:
    """How a session runs.

    Attributes
    ----------
    script : the crew's actions (None: keyboard).
    out_dir : folder for the session export, the processed track, the sheet and the plots.
    device_wait_s : wall-clock time a device has to deliver its first data at the device check.
    setup_points : number of CPIII points measured for the free station.
    live : process each interval as soon as its closing fix is accepted.
    tolerances : tolerance set of the live interval summaries and of the survey sheet (None: the
        project's setting); resolved once by :func:`survey.session.interval.tolerance_set_name`.
    reopen : on resume, reopen an ended session to add intervals (the script, if any, starts again).
    script_path : the script's file, kept with a reopen (a "script_file" event) so that a resume of
        the reopened session runs the same script without being told again.
    project : the project as the crew gave it on the command line (a name or a folder), for the
        commands the messages suggest.
    """

    script: list[Action] | None = None
    out_dir: Path | None = None
    device_wait_s: float = 10.0
    setup_points: int = 8
    live: bool = True
    tolerances: str | None = None
    reopen: bool = False
    script_path: str | None = None
    project: str = "PROJECT"


@dataclass
class SessionOutcome:
    """What the session produced (paths are None when not written)."""

    session_id: int
    fixes_accepted: int
    session_dir: Path | None = None
    track_csv: Path | None = None
    xlsx: Path | None = None
    plots_dir: Path | None = None
    plots: list[Path] = field(default_factory=list)
    result: object = None
    notes: list[str] = field(default_factory=list)


class FieldSession(StationSetupSteps, LiveFiltering):
    """One field session on the project store.

    Parameters
    ----------
    store : the open project store.
    name : session name.
    config : how to run.
    world : a :class:`survey.session.simworld.SimWorld` (simulated session) or None.
    ports : device -> port for real devices (``imu``, ``odometer``, ``gauge``, ``totalstation``).
    console : rich console for the screen (stderr).
    keys : a key source with ``get() -> str | None`` (interactive) or None.
    resume : continue a stored session instead of creating one.
    """

    def __init__(self, store: ProjectStore, name: str, config: SessionConfig, world=None,
                 ports: dict | None = None, console=None, keys=None, resume: bool = False,
                 device_options: dict | None = None) -> None:
        from rich.console import Console

        self.store = store
        self.name = name
        self.config = config
        self.world = world
        self.ports = dict(ports or {})
        self.device_options = dict(device_options or {})
        self.console = console or Console(stderr=True)
        self.keys = keys
        self.resume = resume
        self.screen = ScreenState(session=name)
        self.settings = store.settings()
        # one tolerance set for the live summaries and the final sheet
        self.tolerance_name = tolerance_set_name(config.tolerances or self.settings.tolerance_set)
        self.rec = None
        self.acq: Acquisition | None = None
        self.ts = None
        self.writer: RecordWriter | None = None
        self.setup_id: int | None = None
        # session state (rebuilt from the store on resume)
        self.static_start_s: float | None = None
        self.aligned = False
        self.paused = False
        self.device_pause = ""
        self.direction = 1.0
        self.last_fix: FixRecord | None = None
        self.last_fix_distance_m = 0.0
        self.last_fix_chainage_m = float("nan")
        self.accepted_fixes: list[FixRecord] = []
        self.pending: tuple[int, FixRecord, object] | None = None
        self.script_index = 0
        self.stop_started_s: float | None = None
        self.stop_count = 0
        self.ended = False
        self.note_buffer: str | None = None
        self._action_state: dict = {}
        self._live = None
        self._live_thread: threading.Thread | None = None
        self._live_fed_t = -math.inf
        self._design = None
        self._tolerances = None
        self._world_held = False
        self._hold_ends: dict[int, float] = {}  # stops an interactive simulated world stands at longer
        self._fix_wall_s = -math.inf  # monotonic time of the last accepted fix (CREW_LINGER_S)
        #: resume: the setup number (1-based) of a station change the crash interrupted
        self._station_resumed: int | None = None
        self._fix_distance_pending = False
        self._resume_moved = False  # resume: the trolley moved in the interrupted ``move`` step
        self._resume_seen_t = -math.inf  # resume: session time of the crew's last script step
        # resume: the end of the last stop stored; the data streamed again up to it are that stop,
        # not a new one (its row can be committed before the odometer rows that show it)
        self._last_stop_end_s = -math.inf
        self._live_replay: list[FixRecord] = []  # resume: stored fixes waiting for their data
        self._summarised: set[tuple[float, float]] = set()  # resume: the intervals summarised before
        self._confirm_end = False
        self._key_prompt = ""  # a question of the station setup, shown instead of the loop's keys
        self._live_display = None
        self.interval_seconds: list[float] = []
        self._intervals_to_store: list[tuple] = []

    # ================================================================== time and motion
    def now(self) -> float:
        """Session time now."""
        if self.world is not None:
            return self.world.now()
        return time.monotonic() - self.acq.tb.host_t0

    def _odometer(self) -> np.ndarray:
        return self.acq.buffers.array("odo", 2)

    def motion(self) -> tuple[bool, float, float]:
        """(standing, speed, distance) from the latest odometer second."""
        w = self.acq.buffers.tail("odo", STAND_WINDOW_S)
        if w.shape[0] < 2:
            return True, 0.0, float(w[-1, 1]) if w.shape[0] else 0.0
        od = w
        moved = float(np.ptp(w[:, 1]))
        dt = max(float(w[-1, 0] - w[0, 0]), 1e-9)
        return moved < STAND_TOLERANCE_M, abs(float(w[-1, 1] - w[0, 1])) / dt, float(od[-1, 1])

    def data_time(self) -> float:
        """Newest session time covered by the IMU and odometer data."""
        return min(self.acq.buffers.last_t("imu"), self.acq.buffers.last_t("odo"))

    @contextlib.contextmanager
    def crew_busy(self):
        """While the crew measures: a simulated world waits (its clock stands still)."""
        if self.world is None:
            yield
            return
        with self.world.crew_busy():
            yield
        now = time.monotonic()
        for k in self.acq.last_data_host:  # the streams paused with the clock: not a device fault
            self.acq.last_data_host[k] = max(self.acq.last_data_host[k], now)

    # ================================================================== store helpers
    def _event(self, kind: str, detail: str = "", t_s: float | None = None) -> None:
        self.store.add_event(self.rec.session_id, SessionEvent(self.now() if t_s is None else t_s, kind, detail))

    def say(self, text: str) -> None:
        """A message on the screen and in the scroll-back."""
        self.screen.message = text
        self.console.print(text, highlight=False, markup=False)  # labels and paths printed as they are

    # ================================================================== start
    def open_session(self) -> None:
        """Create the session (or load it on resume) and its time base."""
        from survey.store import StoreError

        if self.rec is not None:  # already open
            return
        if self.resume:
            self.rec = self.store.session(self.name)
            if self.rec.source != "live":
                raise SessionAbort(f"session {self.name!r} was imported, not recorded here")
            if self.rec.state == "ended" and self.config.reopen:
                # reopened to add intervals: the session goes on from its last data; the next end
                # processes it again (a new "final" run)
                last = max(self._stored_state()["last"].values(), default=0.0)
                if self.world is not None and self.world.finished(last):
                    # checked before the session is switched back to open: a failed reopen must
                    # leave it ended as it was
                    raise SessionAbort(f"session {self.name!r}: its simulated survey is recorded to the end "
                                       f"(t = {last:.3f} s); reopening it has nothing to add",
                                       "start a new session to survey more")
                self.store.set_session_state(self.rec.session_id, "open")
                self._event("reopened", f"data up to t = {last:.3f} s", t_s=last)
                if self.config.script_path:
                    self._event("script_file", json.dumps({"script": self.config.script_path}), t_s=last)
                self.rec = self.store.session(self.name)
            elif self.rec.state == "ended":
                if any(r.kind == "final" for r in self.store.processing_runs(self.rec.session_id)):
                    raise SessionAbort(f"session {self.name!r} has ended; nothing to resume",
                                       f"`trolley survey resume {self.config.project} --session {self.name} --reopen` "
                                       "reopens it to add intervals; or start a new session")
                return  # ended but its final processing did not finish: run() does only that
        else:
            design = self.store.alignment()
            meta = self.store.session_meta("alignment.xml" if design else None)
            if self.world is not None:
                meta = replace(meta, initial_heading_rad=self.world.sim.session.meta.initial_heading_rad,
                               static_s=self.world.sim.session.meta.static_s)
            try:
                self.rec = self.store.create_session(self.name, meta, alignment_id=design.alignment_id if design else None)
            except StoreError as exc:
                raise SessionAbort(str(exc), f"choose another --session name, or `trolley survey resume "
                                              f"{self.config.project} --session {self.name}` to continue that one") from None
        if self.rec.alignment_id is not None:
            a = self.store.alignment(self.rec.alignment_id)
            self._design = a.design(self.rec.meta.trolley.rail_spacing_m)
        if self.rec.state != "ended":
            self.store.set_session_state(self.rec.session_id, "open")

    def _stored_state(self) -> dict:
        """Everything a resumed session needs, from the store."""
        sid = self.rec.session_id
        events = self.store.events(sid)
        c = self.store.connection
        last = {}
        for table, dev in (("imu_sample", "imu"), ("odometer_sample", "odometer"), ("gauge_sample", "gauge")):
            r = c.execute(f"SELECT MAX(t_s) FROM {table} WHERE session_id = ?", (sid,)).fetchone()
            if r[0] is not None:
                last[dev] = float(r[0])
        return {"events": events, "last": last}

    def start_devices(self) -> None:
        """Start the twins (simulated) or open the ports, then check every device."""
        from drivers.serialport import DeviceError
        from drivers.totalstation import DEFAULT_BAUD, TotalStation

        stored = self._stored_state() if self.resume else {"events": [], "last": {}}
        tb = TimeBase()
        clock_stored = False
        for ev in stored["events"]:
            if ev.kind == "clock":
                tb, clock_stored = TimeBase.from_json(json.loads(ev.detail)), True
        gap = None
        if self.world is None and clock_stored:
            # real devices: the host may have rebooted since (the monotonic clock restarted)
            last = max(stored["last"].values(), default=0.0)
            tb, gap = tb.resumed(last)
            clock_stored = False  # the re-anchored base is stored again below
        self.writer = RecordWriter(self.store.path, self.rec.session_id, flush_interval_s=0.5)
        if self.world is not None:
            from survey.session.simworld import IMU_SOW0, IMU_WEEK, SIM_IMU_TYPE, SIM_ODOMETER

            last = stored["last"]
            t_start = min(last.values()) if last else 0.0
            self.ports = self.world.start(t_start, last)
            if self.config.script is not None:
                # a scripted crew: the world never runs more than SIM_STEP_S ahead of the data, also
                # before the loop (device check, and on resume the replay and the restored setup,
                # which take wall-clock time in which the trolley would otherwise move on unseen)
                # (the streams restart at their own last stored samples: every one must reach its own)
                self.world.clock.limit = self._scripted_world_limit(max(last.values(), default=0.0))
            else:
                self._hold_before_loop(max(last.values(), default=0.0))
            tb.imu_week, tb.imu_sow0_s = IMU_WEEK, IMU_SOW0
            tb.gauge_origin_s = self.world.gauge_t0_s
            if tb.odo_count0 is None:
                tb.odo_count0 = 0
            opts = dict(odometer=SIM_ODOMETER, imu_type=SIM_IMU_TYPE)
        else:
            from drivers import encoder

            opts = dict(odometer=encoder.OdometerConfig(**self.device_options.get("odometer_config", {})),
                        imu_type=self.device_options.get("imu_type"),
                        imu_rate_hz=self.device_options.get("imu_rate_hz"),
                        imu_axes=self.device_options.get("imu_axes", "x,y,z"),
                        bauds={k: int(self.device_options[f"{k}_baud"]) for k in ("imu", "odometer", "gauge")
                               if f"{k}_baud" in self.device_options})
        if "imu" not in self.ports or "totalstation" not in self.ports:
            raise SessionAbort("the devices file must name at least an imu and a totalstation port",
                               'e.g. {"imu": "/dev/ttyUSB0", "odometer": "/dev/ttyUSB1", "totalstation": "/dev/ttyUSB2"}')
        self.acq = Acquisition({k: v for k, v in self.ports.items() if k != "totalstation"}, self.writer, tb,
                               self.world, **opts)
        if self.resume:
            self._load_buffers()
        self.screen.phase = "device check"
        try:
            self.acq.open(OPEN_TIMEOUT_S)
        except DeviceError as exc:
            raise SessionAbort(str(exc), "check the cable and the port name (--devices file); "
                                         "`trolley devices probe` tests one device") from None
        self.ts = TotalStation(self.ports["totalstation"], raw_log=None, timeout_s=3.0,
                               baudrate=int(self.device_options.get("totalstation_baud", DEFAULT_BAUD)))
        from survey.session.acquisition import RawTap, tap_writes

        self.ts.link.parser = RawTap(self.ts.link.parser, "totalstation", self.acq._raw)
        tap_writes(self.ts.link, self.acq._raw)
        try:
            self.ts.link.open(OPEN_TIMEOUT_S)
        except DeviceError as exc:
            raise SessionAbort(str(exc), "check the total station's cable and port") from None
        if self.world is not None:
            self.world.run_twins()
        self.acq.start()
        self.check_devices()
        if gap is not None:
            self._event("time_gap", json.dumps(gap), t_s=gap["resumed_at_s"])
            self.say(f"the host restarted since the last data (t = {gap['last_stored_s']:.1f} s): the session "
                     f"continues at t = {gap['resumed_at_s']:.1f} s; take a fix before moving on")
        if not clock_stored:  # at the start, and at every resume on real devices (the wall-clock anchor)
            self._event("clock", json.dumps(tb.to_json()), t_s=0.0 if not self.resume else self.now())

    def _load_buffers(self) -> None:
        sid = self.rec.session_id
        t, w, f = self.store.imu_arrays(sid)
        self.acq.buffers.add("imu", np.column_stack([t, w, f]))
        ot, od = self.store.odometer_arrays(sid)
        self.acq.buffers.add("odo", np.column_stack([ot, od]))
        gt, gm = self.store.gauge_arrays(sid)
        self.acq.buffers.add("gauge", np.column_stack([gt, gm]))
        self.acq._odo_reply_index = 0

    def check_devices(self) -> None:
        """Every device probed, its status shown; a failing one stops the start with the reason."""
        from rich.markup import escape
        from rich.table import Table

        from drivers import encoder
        from drivers.geocom import GeoComError
        from drivers.serialport import DeviceError
        from trolley import units

        table = Table(title="device check")
        for col in ("device", "port", "status"):
            table.add_column(col)
        problems = []
        try:
            self.ts.link.start()
            self.ts.link.write(b"\n")
            self.ts.null_proc()
            rel, ver, sub = self.ts.sw_version()
            # what the instrument holds before the session sets it (StationSetupSteps.use_prism)
            held = f"{units.m_to_mm(self.ts.prism_constant()):+.1f} mm"
            table.add_row("totalstation", self.ports["totalstation"],
                          f"[green]ok[/] GeoCOM {rel}.{ver}.{sub}, prism constant {held} (project: CPIII "
                          f"{units.m_to_mm(self.settings.cpiii_prism_constant_m):+.1f}, trolley "
                          f"{units.m_to_mm(self.settings.trolley_prism_constant_m):+.1f} mm)")
        except (GeoComError, DeviceError) as exc:
            table.add_row("totalstation", escape(str(self.ports["totalstation"])), f"[red]{escape(str(exc))}[/]")
            problems.append(("totalstation", str(exc), "switch the instrument on, check GeoCOM on the serial port "
                                                       "and its baud rate"))
        # a simulated session resumed after its last sample: its twins have nothing left to send,
        # and the resume goes on to the end (bug hunt 2026-11-26: it stopped here for good)
        over = self.world is not None and self.resume and self.world.finished(self.data_time())
        deadline = time.monotonic() + (0.0 if over else self.config.device_wait_s)
        while time.monotonic() < deadline and any(n == 0 for n in self._new_samples().values()):
            time.sleep(0.05)
        for name, n in self._new_samples().items():
            port = self.ports[name]
            if n == 0 and over:
                table.add_row(name, port, "[green]ok[/] the simulated survey is over: nothing left to send")
                continue
            mismatch = (encoder.width_mismatch_error(self.acq.links[name].stats, self.acq.odo_cfg, port)
                        if name == "odometer" else None)
            if n == 0 and mismatch is not None:  # replies arrive, but of another counter width
                table.add_row(name, port, f"[red]{escape(str(mismatch))}[/]")
                problems.append((name, str(mismatch), "set the counter width in the devices file"))
            elif n == 0:
                err = self.acq.links[name].last_error or "no data"
                table.add_row(name, port, f"[red]no data in {self.config.device_wait_s:g} s ({escape(str(err))})[/]")
                problems.append((name, f"no data from {port} in {self.config.device_wait_s:g} s",
                                 "check power, cable and baud rate; `trolley devices record` shows what arrives"))
            else:
                table.add_row(name, port, f"[green]ok[/] {n} samples")
        self.console.print(table)
        if problems:
            name, why, hint = problems[0]
            raise SessionAbort(f"{name}: {why}", hint)

    def _new_samples(self) -> dict[str, int]:
        return dict(self.acq.samples)

    def _ask_key(self, prompt: str, allowed: str) -> str:
        """Wait for one of the ``allowed`` keys; ``prompt`` is the one set of keys on the screen."""
        self.console.print(f"[bold]{escape(prompt)}[/]", highlight=False)
        self._key_prompt = prompt
        try:
            while True:
                if self._live_display is not None:
                    self.screen.prompt = prompt
                    self._live_display.update(render(self.screen))
                k = self.keys.get() if self.keys else None
                if k is not None and k.lower() in allowed:
                    return k.lower()
                self.acq.pump()
                time.sleep(TICK_S)
        finally:
            self._key_prompt = ""

    # ================================================================== static alignment
    def _alignment_step(self) -> None:
        if self.aligned:
            return
        imu_t = self.acq.buffers.last_t("imu")
        if not np.isfinite(imu_t):
            return
        static_s = self.rec.meta.static_s
        if self.static_start_s is None:
            self.static_start_s = float(self.acq.buffers.array("imu", 7)[0, 0])
        t_end = self.static_start_s + static_s
        od = self._odometer()
        w = od[(od[:, 0] >= self.static_start_s) & (od[:, 0] <= min(t_end, od[-1, 0] if od.shape[0] else t_end))]
        if w.shape[0] > 1 and np.ptp(w[:, 1]) > STAND_TOLERANCE_M:
            moved_at = float(w[np.argmax(np.abs(w[:, 1] - w[0, 1]) > STAND_TOLERANCE_M), 0])
            self.static_start_s = moved_at + STAND_WINDOW_S
            self.say(f"the trolley moved at t = {moved_at:.1f} s: static alignment restarts; keep it still")
            self._event("alignment_restart", f"{self.static_start_s!r}")
            return
        done = min(imu_t, od[-1, 0] if od.shape[0] else imu_t) - self.static_start_s
        self.screen.progress = max(0.0, min(1.0, done / static_s))
        self.screen.phase = f"static alignment: {max(static_s - done, 0.0):5.0f} s to go"
        if done >= static_s:
            self.aligned = True
            # the static alignment is the first stop: the trolley stood still all along it
            self.stop_started_s = self.static_start_s
            self.screen.progress = None
            self._event("aligned", json.dumps({"static_start_s": self.static_start_s, "static_s": static_s}))
            fixed_here = bool(self.accepted_fixes) and abs(self.motion()[2] - self.last_fix_distance_m) <= 1.0
            self.say("static alignment done: " + ("push the trolley to the next stop" if fixed_here else
                                                  "f = take a fix here, then push the trolley to the next stop"))
            self.screen.phase = "surveying"

    # ================================================================== fixes
    def take_fix(self) -> bool:
        """Measure the prism; False when it cannot be done now (the reason is on the screen)."""
        from drivers.geocom import GeoComError
        from drivers.serialport import DeviceError

        standing, _, dist = self.motion()
        if not standing:
            if self.config.script is None:
                self.say("the trolley is moving: a fix is taken when it stands")
            return False
        try:
            with self.crew_busy():
                t = self.now()
                if self.world is not None:
                    self.world.aim_at_prism(t)
                self.use_prism("trolley")
                self.ts.fine_adjust()
                m = self.ts.measure()
        except (GeoComError, DeviceError) as exc:
            self._device_fault(f"total station: {exc}")
            return False
        label = f"FIX{len(self.store.fixes(self.rec.session_id)) + 1:03d}"
        here = self.grid_coordinates(m)
        fix = FixRecord(t, label, *here, *self.fix_sigmas(here), setup_id=self.setup_id)
        verdict = self._live_verdict(fix)
        accepted = verdict is None or bool(verdict.accepted)
        reason = "accepted" if accepted else f"{SUSPICIOUS}: {verdict.reason}"
        fix_id = self.store.add_fix(self.rec.session_id, replace(fix, accepted=accepted, reason=reason))
        fix = replace(fix, fix_id=fix_id, accepted=accepted, reason=reason)
        if accepted:
            # said first: _accepted starts the interval's processing, whose summary follows on its own thread
            self.say(f"fix {label} accepted at t = {t:.1f} s"
                     + (f" (innovation {1e3 * np.linalg.norm(verdict.innovation_enh_m):.2f} mm)" if verdict else "")
                     + (f"; the simulated trolley moves on in {CREW_LINGER_S:g} s (s = station change here first)"
                        if self.world is not None and self.config.script is None and self.aligned else ""))
            self._accepted(fix, dist)
        else:
            self.pending = (fix_id, fix, verdict)
            inn = 1e3 * np.asarray(verdict.innovation_enh_m)
            self.say(f"suspicious fix {label}: innovation E {inn[0]:+.1f} N {inn[1]:+.1f} H {inn[2]:+.1f} mm "
                     f"(NIS {verdict.nis:.1f}): {verdict.reason}. r = measure again, a = accept anyway")
        return True

    def _set_last_fix(self, fix: FixRecord | None, distance_m: float | None = None) -> None:
        """The fix the live chainage and the distance since the last fix count from (None: no fix):
        its odometer distance (``distance_m``, else the odometer at the fix time) and its chainage
        on the design."""
        self.last_fix = fix
        if fix is None:
            self.last_fix_distance_m, self.last_fix_chainage_m = 0.0, float("nan")
            return
        self._fix_distance_pending = False
        if distance_m is None:
            od = self._odometer()
            if not od.shape[0] or od[-1, 0] < fix.t_s:
                # after a resume the fix may be newer than the odometer data stored before the
                # crash: the distance at the fix is taken when the data up to it have arrived
                # (tick), and until then the chainage is not known
                self._fix_distance_pending = True
                distance_m = float(od[-1, 1]) if od.shape[0] else 0.0
            else:
                distance_m = float(np.interp(fix.t_s, od[:, 0], od[:, 1]))
        self.last_fix_distance_m = distance_m
        self.last_fix_chainage_m = float("nan")
        if self._design is not None:
            p = self._design.project(np.array([fix.e_m]), np.array([fix.n_m]))
            self.last_fix_chainage_m = float(np.asarray(p.chainage_m).ravel()[0])

    def _accepted(self, fix: FixRecord, distance_m: float | None) -> None:
        self.accepted_fixes.append(fix)
        self._fix_wall_s = time.monotonic()
        self._set_last_fix(fix, distance_m)
        self.screen.fixes_accepted = len(self.accepted_fixes)
        if len(self.accepted_fixes) > 1:
            self._process_interval_async()

    def accept_pending(self) -> None:
        if not self.pending:
            self.screen.message = "no suspicious fix to accept"
            return
        fix_id, fix, _ = self.pending
        self.pending = None
        self.store.decide_fix(fix_id, True, CREW_ACCEPTED)
        if self._live not in (None, False):
            try:
                if self._live_thread is not None:
                    self._live_thread.join()
                self._replay_due()
                self._feed_live(fix.t_s)  # after a resume the filter has not seen these data yet
                self._live.add_fix(fix.t_s, fix.point, np.array([fix.e_m, fix.n_m, fix.h_m]),
                                   np.array([fix.sigma_e_m, fix.sigma_n_m, fix.sigma_h_m]), force_accept=True)
            except Exception:  # the final processing decides again
                pass
        # said first: _accepted starts the interval's processing, whose summary follows on its own thread
        self.say(f"fix {fix.point} accepted by the crew")
        self._accepted(replace(fix, accepted=True), None)  # the odometer at the fix, wherever the trolley is now

    def remeasure_pending(self) -> bool:
        if self.pending:
            fix_id, fix, _ = self.pending
            self.store.decide_fix(fix_id, False, "rejected: measured again")
            self.pending = None
        return self.take_fix()

    def undo_last_fix(self) -> None:
        if not self.accepted_fixes:
            self.say("no fix to undo")
            return
        # the summary of the interval this fix closed is finished and stored before the undo (the
        # crew saw it), so that it is withdrawn with the undo in one transaction; and the live
        # processor is not changed under its smoothing (which would then smooth the interval
        # before this one and queue it under this one's times)
        if self._live_thread is not None:
            self._live_thread.join()
        self._store_intervals()
        fix = self.accepted_fixes.pop()
        # Withdrawn, not recomputed: without its closing fix the interval is open again, and there
        # is no end to smooth it to. The crew takes the fix again (at this stop or further on) and
        # that fix closes the interval and summarises it, as the final processing will see it.
        summary = self._summary_closed_by(fix, self.accepted_fixes[-1] if self.accepted_fixes else None)
        self.store.decide_fix(fix.fix_id, False, "undone by the crew",
                              event=(self.rec.session_id, SessionEvent(self.now(), "undo", fix.point)),
                              withdraw_interval=summary["run_id"] if summary else None)
        if summary and self.screen.last_interval == summary["summary"]:
            self.screen.last_interval, self.screen.last_interval_alarm = "", False
        replay = self._live_replay
        if replay and replay[-1].fix_id == fix.fix_id:
            replay.pop()  # resumed, and not replayed yet: it never will be
        elif self._live is not None:
            try:
                self._live.undo_last_fix()
            except Exception:
                pass
        # chainage and distance count from the previous accepted fix again
        self._set_last_fix(self.accepted_fixes[-1] if self.accepted_fixes else None)
        self.screen.fixes_accepted = len(self.accepted_fixes)
        self.say(f"fix {fix.point} undone" + ("; the summary of its interval is withdrawn (the next fix closes the "
                                              "interval again)" if summary else ""))

    # ================================================================== device faults
    def _device_fault(self, message: str) -> None:
        if not self.device_pause:
            self._event("device_fault", message)
            self.say(f"{message}: session paused; nothing received is lost. It continues when the device is back.")
        self.device_pause = message

    def _check_health(self) -> None:
        if self.world is not None and self.world.clock.standing_still:
            now = time.monotonic()  # the streams wait with the simulated clock: not a fault
            for k in self.acq.last_data_host:
                self.acq.last_data_host[k] = now
        faults = self.acq.faults()
        if self.world is not None and self.world.finished(self.data_time()):
            faults = []  # the simulated survey is over: no more data is right
        if faults:
            self._device_fault("; ".join(f"{f.name}: {f.message or 'fault'}" for f in faults))
        elif self.device_pause and not self.device_pause.startswith("total station"):
            self._event("device_back", self.device_pause)
            self.say(f"devices back ({self.device_pause}); the session continues")
            self.device_pause = ""

    def _total_station_back(self) -> bool:
        from drivers.geocom import GeoComError
        from drivers.serialport import DeviceError

        try:
            self.ts.null_proc()
        except (GeoComError, DeviceError):
            return False
        # it may have restarted (a battery changed) or be another instrument: its prism constant
        # is set and read back again before the next measurement
        self.ts.forget_prism_constant()
        self._event("device_back", self.device_pause)
        self.say("total station answers again; the session continues")
        self.device_pause = ""
        return True

    # ================================================================== the loop
    def tick(self) -> None:
        """One refresh: store, health, alignment, motion, stops, screen."""
        self.acq.pump()
        self._store_intervals()
        self._check_health()
        self._alignment_step()
        self._settle_fix_distance()
        self._replay_due()
        standing, speed, dist = self.motion()
        t = self.now()
        if standing and self.stop_started_s is None and self.aligned and t > self._last_stop_end_s:
            self.stop_started_s = t
            if self.accepted_fixes and abs(dist - self.last_fix_distance_m) > 1.0:
                here = self.shown_station(self.chainage_now(dist))
                # (unknown right after a resume, until the odometer data up to the last fix are in)
                self.say(f"standing at {here:.1f} m: f = take a fix" if np.isfinite(here)
                         else "standing (chainage -): f = take a fix")
        elif not standing and self.stop_started_s is not None:
            self.store.add_stop(self.rec.session_id, self._stop_record(t))
            self.stop_started_s = None
            self.stop_count += 1
        self._hold_at_stop()
        s = self.screen
        s.prompt = self.keys_prompt()
        s.t_s, s.standing, s.speed_m_s = t, standing, speed
        s.distance_since_fix_m = abs(dist - self.last_fix_distance_m) if self.last_fix else dist
        s.chainage_m = self.shown_station(self.chainage_now(dist))
        t_ref = self.last_fix.t_s if self.last_fix else (self.static_start_s or 0.0)
        s.sigma_mm = predicted_sigma_mm(self.rec.meta, s.distance_since_fix_m, t - t_ref)
        s.sigma_fix_here_mm = interval_sigma_mm(self.rec.meta, s.distance_since_fix_m, t - t_ref)
        s.devices = self.acq.health()
        if self.world is not None and self.world.finished(self.data_time()) and self.config.script is None:
            # the last stop ends with the data: the world may wait there for its fix (_hold_at_stop)
            s.message = ("the simulated survey is over: f = take the fix at this last stop, then e = end the session"
                         if self.world.clock.limit is not None else "the simulated survey is over: e = end the session")
        if self.paused:
            s.phase = "PAUSED (train): p to resume"
        elif self.device_pause:
            s.phase = "PAUSED: device fault"
        elif self.aligned:
            s.phase = "surveying"

    def _settle_fix_distance(self) -> None:
        """The odometer distance at the last fix, once the data up to the fix have arrived."""
        if self._fix_distance_pending and self.last_fix is not None:
            od = self._odometer()
            if od.shape[0] and od[-1, 0] >= self.last_fix.t_s:
                self._set_last_fix(self.last_fix)

    def keys_prompt(self) -> str:
        """The one set of keys the crew can use now (shown at the bottom of the screen)."""
        if self._key_prompt:
            return self._key_prompt  # a question of the station setup
        if self.note_buffer is not None:
            return f"note: {self.note_buffer}_  (Enter to save)"
        if self._confirm_end:
            return "end the session? y end | any other key: go on"
        if self.pending:
            return f"suspicious fix {self.pending[1].point}: r measure again | a accept anyway"
        if self.paused:
            return "PAUSED: p resume | n note | e end"
        return KEYS_HELP

    def _stop_record(self, noticed_s: float) -> StopRecord:
        """The stop begun at ``stop_started_s``, whose end was noticed at ``noticed_s``: at the
        chainage where the trolley stood, ending at the last odometer sample still there (the motion
        test notices a departure late, and the static alignment's end later still)."""
        od = self._odometer()
        if not od.shape[0]:
            return StopRecord(self.stop_started_s, noticed_s, f"S{self.stop_count:03d}", float("nan"))
        d0 = float(np.interp(self.stop_started_s, od[:, 0], od[:, 1]))
        span = od[(od[:, 0] >= self.stop_started_s) & (od[:, 0] <= noticed_s)]
        still = span[np.abs(span[:, 1] - d0) <= STAND_TOLERANCE_M]
        t_end = float(still[-1, 0]) if still.shape[0] else noticed_s
        return StopRecord(self.stop_started_s, max(t_end, self.stop_started_s), f"S{self.stop_count:03d}",
                          self.chainage_now(d0))

    def _hold_before_loop(self, stored_s: float) -> None:
        """The crew at the keyboard, until the loop first looks (device check, and on resume the
        restore): the simulated world does not leave the stop it stands at or heads to, whatever
        was done there (:meth:`_hold_at_stop` then decides). A resumed session's world had run
        40-120 simulated s through the device check, past the stop the crew was at.

        At a stop's end (a session killed while the world waited there) it sends ``STOP_GRACE_S``
        of data past what is stored: the device check waits for a sample of every stream (the
        gauge's come every 0.1 s), and the trolley has moved 5 um by then. Each resume there adds
        that much, so a stop is left by time only once the trolley would move more than
        :data:`HELD_MOVE_M` from it in the data sent: by the stop's end + ``STOP_GRACE_S`` alone,
        the third kill at one stop (stored data 0.2 s past its end, the trolley 0.08 mm from it)
        found the world heading for the next stop, and the fix there was lost."""
        from survey.session.simworld import STOP_GRACE_S

        m = self.world.sim.truth.motion
        for k in range(m.stop_end_s.size):
            if m.stop_end_s[k] + STOP_GRACE_S < stored_s - 1e-6:
                if not m.stop_start_s[k] <= stored_s <= m.stop_end_s[k] + 1.0:
                    continue  # a stop the world has left
                s = m.evaluate(np.array([float(m.stop_end_s[k]), stored_s + STOP_GRACE_S]))[0]
                if abs(s[1] - s[0]) > HELD_MOVE_M:
                    continue  # the trolley is leaving it
            end = float(m.stop_end_s[k])
            if m.stop_start_s[k] <= stored_s:
                end = self._hold_ends[k] = max(end, stored_s + STOP_GRACE_S)
            self.world.clock.limit = end
            return
        self.world.clock.limit = None

    def _hold_at_stop(self) -> None:
        """An interactive simulated session: the simulated world does not run past the end of the
        stop it stands at (or is heading to) until the crew has done its part there: the static
        alignment at the first stop, and an accepted fix at every stop (a real trolley waits for its
        crew; the simulator's motion is scripted in time).

        The hold is a limit on the simulated clock, set before the trolley reaches the stop's end,
        not a freeze once the session sees it standing: at ``--speedup 40`` the first stop ends in
        the very tick in which the static alignment ends, and an 8 s stop lasts 0.2 s of wall time,
        so a loaded machine saw the trolley standing only after it had left (its fix key was then
        answered "the trolley is moving"). At the first stop the world stands a little past the
        stop's scripted end, within ``STOP_GRACE_S``, until the alignment has its data."""
        if self.world is None or self.config.script is not None or self.world.clock is None:
            return
        from survey.session.simworld import STOP_GRACE_S

        m = self.world.sim.truth.motion
        clock = self.world.clock
        t = clock.now()
        limit = None
        for k in range(m.stop_end_s.size):
            end = max(float(m.stop_end_s[k]), self._hold_ends.get(k, -math.inf))
            if end < t - 1e-6:
                continue  # a stop the world has left
            aligning = False
            if not self.aligned and self.static_start_s is None:
                aligning = True  # no IMU sample yet: the alignment has not begun
            elif not self.aligned:
                # the static alignment needs its data up to its end, which may lie a sample or
                # two after the stop's scripted end (its window opens with the first IMU sample);
                # one that cannot end at this stop is not waited for (it restarts at a later one)
                needed = self.static_start_s + self.rec.meta.static_s
                aligning = (m.stop_start_s[k] <= self.static_start_s
                            and needed + ALIGNMENT_DATA_MARGIN_S <= end + STOP_GRACE_S)
                if aligning and needed + ALIGNMENT_DATA_MARGIN_S > end:
                    end = self._hold_ends[k] = needed + ALIGNMENT_DATA_MARGIN_S  # kept: the stop is still this one
            at_k = [m.stop_start_s[k] - 1e-6 <= f.t_s <= end + 1e-6 for f in self.accepted_fixes]
            # the crew's last fix was here a moment ago: it may still change the station or undo
            lingering = bool(at_k) and at_k[-1] and time.monotonic() - self._fix_wall_s < CREW_LINGER_S
            fixed = any(at_k) and not lingering
            # (still when the crew has ended: a reopened session goes on from this stop)
            if aligning or not fixed:
                limit = max(end, t)  # never backwards: the streams have sent up to t
                break
        clock.limit = limit

    def _freeze_for(self, flag: str, on: bool) -> None:
        """Freeze (``on``) or thaw the simulated clock when the hold named ``flag`` changes (one
        ``thaw`` per ``freeze``: the holds nest)."""
        if on == getattr(self, flag):
            return
        if on:
            self.world.clock.freeze()
        else:
            self.world.clock.thaw()
        setattr(self, flag, on)

    def shown_station(self, chainage_m: float) -> float:
        """What the crew reads for an internal chainage: the drawing's station after the design's
        station equations (``Alignment.station``), the chainage itself without them. Stored
        records keep the internal chainage."""
        if self._design is None or not np.isfinite(chainage_m):
            return chainage_m
        return float(self._design.station(np.array([chainage_m]))[0])

    def chainage_now(self, dist: float) -> float:
        """Chainage of the trolley at odometer distance ``dist``: the last fix's chainage on the
        design plus the distance since it (NaN while either is unknown)."""
        if not np.isfinite(self.last_fix_chainage_m) or self._fix_distance_pending:
            return float("nan")
        return self.last_fix_chainage_m + self.direction * (dist - self.last_fix_distance_m)

    def _next_action(self) -> Action | None:
        script = self.config.script
        if script is not None:
            while self.script_index < len(script) and script[self.script_index].name == "setup":
                self.script_index += 1
            return script[self.script_index] if self.script_index < len(script) else Action("end")
        if self.keys is None:
            return None
        k = self.keys.get()
        if k is None:
            return None
        if self.note_buffer is not None:
            if k in "\r\n":
                text, self.note_buffer = self.note_buffer.strip(), None
                return Action("note", text=text) if text else None
            self.note_buffer = self.note_buffer[:-1] if k in "\x7f\b" else self.note_buffer + k
            return None
        mapping = {"f": "fix", "a": "accept", "r": "remeasure", "u": "undo", "p": "pause", "t": "turn",
                   "s": "station"}
        k = k.lower()
        if self._confirm_end:
            self._confirm_end = False
            if k == "y":
                return Action("end")
            self.say("the session goes on")
            return None
        if k == "e":
            self._confirm_end = True
            self.say("end the session? y = end it and process, any other key = go on")
            return None
        if k == "n":
            self.note_buffer = ""
            return None
        if k == "p" and self.paused:
            return Action("resume")
        return Action(mapping[k]) if k in mapping else None

    def do(self, a: Action) -> bool:
        """Carry out (a step of) an action; True when it is done."""
        if self.config.script is not None and self.data_time() < self._resume_seen_t and a.name != "accept":
            # resumed: the data have not caught up with what the crew had seen (accepting a
            # suspicious fix stored before the crash needs no new data: its distance is taken
            # when the odometer data up to it are in, as for any fix)
            return False
        st = self._action_state
        standing = self.motion()[0]
        if a.name == "wait":
            st.setdefault("until", self.now() + a.seconds)
            return self.now() >= st["until"]
        if a.name == "note":
            if self._fix_distance_pending:
                return False  # the chainage is known once the odometer data up to the last fix are in
            dist = self.motion()[2]
            self.store.add_note(self.rec.session_id, NoteRecord(self.now(), a.text, self.chainage_now(dist)))
            self.say(f"note at {self.chainage_now(dist):.3f} m: {a.text}")
            return True
        if a.name == "pause":
            self.paused = True
            self._event("pause")
            self.say("paused (train passing): p to resume")
            return True
        if a.name == "resume":
            self.paused = False
            self._event("resume")
            self.say("resumed")
            return True
        if a.name == "turn":
            self.direction = -self.direction
            self._event("turn", f"direction {self.direction:+.0f}")
            self.say("trolley turned around: chainage keeps increasing the right way")
            return True
        if a.name == "undo":
            self.undo_last_fix()
            return True
        if a.name == "accept":
            self.accept_pending()
            return True
        if a.name == "end":
            if self.world is not None and self.config.script is not None:
                # a simulated session records the whole simulated survey
                if not self.world.finished(self.data_time()):
                    return False
            self.ended = True
            return True
        if self.paused or self.device_pause:
            if self.device_pause.startswith("total station") and a.name in ("fix", "remeasure", "station"):
                if not self._total_station_back():
                    return self._blocked("the total station does not answer")
            elif self.paused:
                return self._blocked("paused: p to resume first")
            else:
                return self._blocked(f"waiting for the devices ({self.device_pause})")
        if self.world is not None and a.name in ("stop", "move") and self.world.finished(self.data_time()):
            return True  # the simulated survey is over
        if a.name == "stop":
            return standing
        if a.name == "move":
            if not self.aligned:
                return False
            if not st.get("moved"):
                st["moved"], self._resume_moved = (not standing) or self._resume_moved, False
                return False
            return standing
        if a.name == "station":
            if self.world is not None and self.world.finished(self.now()):
                return True
            return self.station_change() or self.config.script is None
        if a.name in ("fix", "remeasure"):
            if not standing:
                if self.config.script is None:  # a key press while moving is answered, then dropped
                    self.say(f"{'f' if a.name == 'fix' else 'r'} ignored: the trolley is moving; "
                             "a fix is taken when it stands")
                    return True
                return False
            if self.world is not None and self.config.script is not None and self.world.finished(self.now()):
                return True  # a scripted fix past the end of the simulated survey
            # (at the keyboard the world waits for the fix at the last stop at the end of its data)
            ok = self.remeasure_pending() if a.name == "remeasure" else self.take_fix()
            return ok or self.config.script is None
        return True

    def _step_world(self) -> None:
        """A scripted crew sees every simulated second: the world never runs more than
        ``SIM_STEP_S`` ahead of the data the crew has seen. A loaded machine then slows the world
        down instead of letting the trolley leave a stop unseen."""
        if self.world is None or self.config.script is None:
            return
        clock = self.world.clock
        d = self.data_time()
        base = d if np.isfinite(d) else clock.now()
        clock.limit = max(self._scripted_world_limit(base), clock.now())  # never backwards

    def _scripted_world_limit(self, seen_s: float) -> float:
        """How far a scripted crew's world may run once the crew has seen the data up to ``seen_s``:
        ``SIM_STEP_S`` further, but not past the end of a stop those data stand in (plus
        ``STOP_GRACE_S``) before the crew has seen that end. A session resumed or reopened at
        the very end of a stop (an interactive world waits there for the fix) still finds the
        trolley standing; with the 2 s step alone it had left, and the fix was taken at the
        next stop."""
        from survey.session.simworld import STOP_GRACE_S, stop_index_at

        limit = seen_s + SIM_STEP_S
        k = stop_index_at(self.world.sim, seen_s)
        if k >= 0:
            end = float(self.world.sim.truth.motion.stop_end_s[k]) + STOP_GRACE_S
            if seen_s < end - 1e-9:
                limit = min(limit, end)
        return limit

    def _hold_world(self, on: bool) -> None:
        """Freeze (or let run) a simulated world's clock for a scripted crew."""
        if self.world is None or self.config.script is None:
            return
        self._freeze_for("_world_held", on)

    def _blocked(self, why: str) -> bool:
        """A script waits for the condition; a key press is answered and dropped (so that the next
        key, e.g. ``p``, is read)."""
        if self.config.script is not None:
            return False
        self.say(why)
        return True

    def loop(self) -> None:
        """The stop-and-go loop until the session ends."""
        from rich.live import Live

        current: Action | None = None
        with Live(render(self.screen), console=self.console, refresh_per_second=8, transient=True,
                  redirect_stderr=False, redirect_stdout=False) as live:
            self._live_display = live
            while not self.ended:
                self.tick()
                if current is None:
                    current = self._next_action()
                    self._action_state = {}
                # a scripted crew in a simulated world: the world runs only while the crew waits for
                # it (move, wait, stop, end, or a fix waiting for the trolley to stand); the crew's
                # own actions take no simulated time, however slow the machine
                self._hold_world(current is not None)
                self._step_world()
                done = current is not None and self.do(current)
                if not done:
                    self._hold_world(False)
                if done:
                    if self.config.script is not None:
                        self.script_index += 1
                        self._event("script", self._script_event_detail())
                    current = None
                self.screen.prompt = self.keys_prompt()
                live.update(render(self.screen))
                # a stepped simulated world advances at most SIM_STEP_S per look: look more often
                time.sleep(TICK_S if self.world is None or self.config.script is None else TICK_S / 2)
        self._live_display = None

    # ================================================================== resume
    def restore(self) -> None:
        """Rebuild the crew-visible state from the store (fixes, alignment, pauses, script position)."""
        sid = self.rec.session_id
        for ev in self.store.events(sid):
            if ev.kind == "aligned":
                d = json.loads(ev.detail)
                self.static_start_s, self.aligned = d["static_start_s"], True
            elif ev.kind == "alignment_restart":
                self.static_start_s = float(ev.detail)
            elif ev.kind == "pause":
                self.paused = True
            elif ev.kind == "resume":
                self.paused = False
            elif ev.kind == "turn":
                self.direction = -self.direction
            elif ev.kind == "script":
                self.script_index = int(ev.detail.split()[0])
            elif ev.kind == "reopened":  # the script of a reopened session starts again
                self.script_index = 0
        fixes = self.store.fixes(sid, accepted_only=True)
        stops = self.store.stops(sid)
        self.stop_count = len(stops)
        self._last_stop_end_s = stops[-1].t_end_s if stops else -math.inf
        self._restore_open_stop()
        self.accepted_fixes.extend(fixes)
        self._set_last_fix(fixes[-1] if fixes else None)
        all_fixes = self.store.fixes(sid)
        if self.world is not None:
            self.world.restore_fix_attempts([f.t_s for f in all_fixes])
        self._resume_script_step(all_fixes)
        self.screen.fixes_accepted = len(self.accepted_fixes)
        if self.aligned and self.accepted_fixes and self.config.live:
            self._replay_live()
        # a suspicious fix the crew had not decided on yet is offered again
        if all_fixes and not all_fixes[-1].accepted and all_fixes[-1].reason.startswith(SUSPICIOUS):
            f = all_fixes[-1]
            self.pending = (f.fix_id, f, None)
            self.say(f"suspicious fix {f.point} still to decide ({f.reason}): r = measure again, a = accept anyway")
        script = self.config.script
        if script is not None and 0 < self.script_index and not self.config.reopen:
            # where a script given again (or another one) goes on: never silently past lines
            if self.script_index < len(script):
                a = script[self.script_index]
                self.say(f"the script goes on at its step {self.script_index + 1} of {len(script)} (line {a.line}: "
                         f"{a.name}{' ' + a.text if a.text else ''}): the steps before it were done before the "
                         "interruption")
            else:
                self.say(f"the script's {len(script)} steps were all done before the interruption")
        self._event("resumed", f"data up to t = {self.data_time():.3f} s")
        self.say(f"resumed session {self.name}: {len(self.accepted_fixes)} fixes kept, "
                 f"data up to t = {self.data_time():.1f} s")

    def _restore_open_stop(self) -> None:
        """A stop the trolley stood at when the session died (stored only when it is left): it began
        when the stored odometer came to rest, not at the resume."""
        if not self.aligned:
            return
        t, d = self.store.odometer_arrays(self.rec.session_id)
        if t.size < 2:
            return
        moved = np.flatnonzero(np.abs(d - d[-1]) > STAND_TOLERANCE_M)
        rest = float(t[moved[-1] + 1]) if moved.size else float(t[0])
        if moved.size == 0 and self.static_start_s is not None:
            rest = max(rest, float(self.static_start_s))
        if rest > self._last_stop_end_s and t[-1] - rest >= STAND_WINDOW_S:
            self.stop_started_s = rest

    def _resume_script_step(self, all_fixes: list[FixRecord]) -> None:
        """The script step the crash interrupted: a fix or a note stored after the last ``script``
        event was that step (not taken twice); a station change begun after it is continued from
        its first step not stored (``_station_change``)."""
        script = self.config.script
        if script is None or self.script_index >= len(script):
            return
        events = self.store.events(self.rec.session_id)
        last = max((i for i, e in enumerate(events) if e.kind in ("script", "reopened")), default=-1)
        last_step_t = events[last].t_s if last >= 0 else -math.inf
        a = script[self.script_index]
        # the crew had seen the world up to its last step: the data streamed again from before it
        # (committed up to 0.5 s late) are the past, not what the next step waits for
        self._resume_seen_t = last_step_t
        done = False
        if a.name in ("fix", "remeasure"):
            detail = events[last].detail.split() if last >= 0 and events[last].kind == "script" else []
            if len(detail) > 1:     # the newest fix id at the last step: a fix stored since is this step's
                done = max((f.fix_id or 0 for f in all_fixes), default=0) > int(detail[1])
            else:                   # a store of before 2026-11-26 (or a reopened session): by time
                done = bool(all_fixes) and all_fixes[-1].t_s > last_step_t
        elif a.name == "note":
            done = any(n.t_s >= last_step_t and n.text == a.text for n in self.store.notes(self.rec.session_id))
        elif a.name in ("undo", "turn", "pause", "resume"):
            # each stores its event with its effect (undo: in one transaction with the decision):
            # done again it would undo the fix before, or turn the trolley back
            done = any(e.kind == a.name for e in events[last + 1:])
        elif a.name == "station":
            changes = [e for e in events[last + 1:] if e.kind == "station_change"]
            if changes:
                self._station_resumed = int(changes[-1].detail.split()[-1])
        elif a.name == "move":
            # the trolley moved since the step began: the step waits for it to stand, not to move
            # again (else the crew would miss the stop it was arriving at when the session died)
            od = self._odometer()
            if od.shape[0] and np.isfinite(last_step_t):
                d0 = float(np.interp(last_step_t, od[:, 0], od[:, 1]))
                self._resume_moved = bool(np.max(np.abs(od[od[:, 0] >= last_step_t, 1] - d0), initial=0.0)
                                          > STAND_TOLERANCE_M)
        if done:
            self.script_index += 1
            self._event("script", self._script_event_detail())

    def _script_event_detail(self) -> str:
        """A ``script`` event's detail: the next step's index and the newest fix's id when it was
        stored, so that a resume knows whether a fix was stored after it even at the same
        simulated time (a crew's fix takes none: by time, a kill between the fix and its step's
        event made the resume take that fix again)."""
        ids = [f.fix_id for f in self.store.fixes(self.rec.session_id) if f.fix_id is not None]
        return f"{self.script_index} {max(ids, default=0)}"

    # ================================================================== end
    def finish(self) -> SessionOutcome:
        """Stop the devices, re-process the whole session, write the sheet and the plots."""
        # the stop the session ends at: it has no departure to store it (tick)
        final_stop = self._stop_record(self.now()) if self.stop_started_s is not None else None
        self._shutdown()
        self._store_intervals()
        self.store.end_session(self.rec.session_id, SessionEvent(self.now(), "end", ""), final_stop)
        return self._final_processing()

    def _final_processing(self) -> SessionOutcome:
        if not self.accepted_fixes:
            self.accepted_fixes = self.store.fixes(self.rec.session_id, accepted_only=True)
        if self.static_start_s is None:
            for ev in self.store.events(self.rec.session_id):
                if ev.kind == "aligned":
                    self.static_start_s = json.loads(ev.detail)["static_start_s"]
        out = SessionOutcome(self.rec.session_id, len(self.accepted_fixes))
        if self.config.out_dir is None or len(self.accepted_fixes) < 2:
            if len(self.accepted_fixes) < 2:
                self.say("fewer than two accepted fixes: nothing to process")
                if self.config.out_dir is not None:
                    # the setups, stops and notes still reach an output (bug hunt 2026-11-26)
                    from survey.fieldrecord import field_record, write_field_record

                    try:
                        folder = Path(self.config.out_dir) / "processed"
                        folder.mkdir(parents=True, exist_ok=True)
                        path = write_field_record(folder, field_record(self.store, self.name))
                        self.say(f"field record (setups, fixes, stops, notes): {path}")
                    except OSError as exc:
                        self.say(f"the field record could not be written into {self.config.out_dir} ({exc}); "
                                 "the session is stored")
            return out
        from survey.errors import os_error_text
        from survey.session.final import process_stored_session

        try:
            return process_stored_session(self.store, self.name, self.config.out_dir, out, self.console,
                                          self.tolerance_name)
        except OSError as exc:
            # a full disk names no file: say which folder the end was writing, and that nothing is lost
            raise SessionAbort(f"end of session: cannot write the results into {self.config.out_dir} "
                               f"({os_error_text(exc)}); the session is stored",
                               f"free space (or fix the folder), then `trolley survey resume {self.config.project} --session "
                               f"{self.name}` does the end again") from None

    def _shutdown(self) -> None:
        if self._live_thread is not None:
            self._live_thread.join()
        if self.acq is not None:
            self.acq.stop()
        if self.ts is not None:
            self.ts.close()
        if self.writer is not None:
            self.writer.close()
        if self.world is not None:
            self.world.stop()

    def run(self) -> SessionOutcome:
        """The whole session: start (or resume), setup, alignment, loop, end."""
        self.open_session()
        if self.rec.state == "ended":  # resumed after a crash during the final processing
            return self._final_processing()
        try:
            self.start_devices()
            if self.resume:
                self.restore()
            self.station_setup()
            self.loop()
        except BaseException:
            self._shutdown()
            raise
        return self.finish()

