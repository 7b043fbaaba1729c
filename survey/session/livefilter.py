"""Live processing of a field session: the incremental filter fed as the data arrive, the
innovation check of each fix, and each interval smoothed and checked in a background thread.

A mixin of :class:`survey.session.fieldsession.FieldSession`. The processor is
``trolley.live.LiveProcessor``; the interval's geometry and defects ``survey.session.interval``.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np

from survey.store import FixRecord
from rich.markup import escape
from rich.text import Text

#: a fix needs the data up to this long before its time (one period of the slowest stream it uses)
DATA_SLACK_S = 0.02


class LiveFiltering:
    """The live filter of a session (mixin of ``FieldSession``)."""

    def _live_processor(self):
        """The incremental processor (``trolley.live``), created after the static alignment."""
        if not self.config.live or self._live is False:
            return None
        if self._live is None:
            try:
                from trolley.live import LiveProcessor
            except ImportError:
                self._live = False
                return None
            self._live = LiveProcessor(self.rec.meta, self._design, grid=self.store.site_grid()
                                       if self.rec.meta.crs else None)
            imu = self.acq.buffers.array("imu", 7)
            t0 = self.static_start_s if self.static_start_s is not None else imu[0, 0]
            sel = (imu[:, 0] >= t0) & (imu[:, 0] <= t0 + self.rec.meta.static_s)
            self._live.align(imu[sel, 0], imu[sel, 1:4], imu[sel, 4:7])
            self._live_fed_t = float(imu[sel, 0][-1])
            for f in self.accepted_fixes:  # fixes taken during the static alignment
                if f.t_s <= self._live_fed_t:
                    self._add_fix(self._live, f, force_accept=True)
        return self._live

    def _add_fix(self, lp, fix: FixRecord, force_accept: bool = False):
        """Hand a stored fix to the live processor with its sigmas and the covariances between its
        axes (``ProjectStore.fix_covariances``): the live gate sees it as the final processing does."""
        return lp.add_fix(fix.t_s, fix.point, np.array([fix.e_m, fix.n_m, fix.h_m]),
                          np.array([fix.sigma_e_m, fix.sigma_n_m, fix.sigma_h_m]), force_accept=force_accept,
                          cov_m2=self.store.fix_covariances(self.rec.session_id, [fix])[0])

    def _feed_live(self, t_until: float) -> None:
        lp = self._live
        imu = self.acq.buffers.array("imu", 7)
        od = self._odometer()
        g = self.acq.buffers.array("gauge", 2)
        # only what has fully arrived: a sample fed late would leave a hole in the dead reckoning
        a, b = self._live_fed_t, min(t_until, self.data_time())
        if b <= a:
            return
        si = (imu[:, 0] > a) & (imu[:, 0] <= b)
        so = (od[:, 0] > a) & (od[:, 0] <= b)
        sg = (g[:, 0] > a) & (g[:, 0] <= b)
        if np.any(si):
            lp.add_samples(imu[si, 0], imu[si, 1:4], imu[si, 4:7], od[so, 0], od[so, 1],
                           g[sg, 0] if np.any(sg) else None, g[sg, 1] if np.any(sg) else None)
            self._live_fed_t = b

    def _live_verdict(self, fix: FixRecord):
        if not self.aligned:
            return None
        lp = self._live_processor()
        if lp is None:
            return None
        try:
            # the data up to the fix time must be there before the prediction
            # every stream up to its last sample before the fix (the odometer's period is 10 ms)
            needed = fix.t_s - DATA_SLACK_S
            deadline = time.monotonic() + 10.0
            while self.data_time() < needed and time.monotonic() < deadline:
                self.acq.pump()
                time.sleep(0.01)
            if self.data_time() < needed:
                self.console.print("[yellow]the data up to the fix have not arrived: no live check of this fix[/]")
                return None
            if self._live_thread is not None:
                self._live_thread.join()
            self._replay_due()  # resumed: the stored fixes first, now that their data are in
            if self._live is False:
                return None
            self._feed_live(fix.t_s)
            return self._add_fix(lp, fix)
        except Exception as exc:  # never stop the survey for the live view
            self.console.print(f"[yellow]live processing unavailable: {escape(str(exc))}[/]", highlight=False)
            self._live = False
            return None

    def _process_interval_async(self) -> None:
        lp = self._live if self._live not in (None, False) else None
        if lp is None:
            return
        t_start, t_end = self.accepted_fixes[-2].t_s, self.accepted_fixes[-1].t_s
        if self._live_thread is not None:
            self._live_thread.join()
        self._live_thread = threading.Thread(target=self._summarise_interval, args=(lp, t_start, t_end),
                                             name="interval", daemon=True)
        self._live_thread.start()

    def _summarise_interval(self, lp, t_start: float, t_end: float) -> None:
        """Smooth the interval closed by the processor's last fix, check it, show its summary and
        queue it for :meth:`_store_intervals` (on the interval thread, or the session's on resume)."""
        from survey.session.interval import defects_text, interval_check, tolerance_set

        try:
            t0 = time.perf_counter()
            r = lp.smooth_last_interval()
            if self._tolerances is None:
                self._tolerances = tolerance_set(self.tolerance_name)
            tr = self.rec.meta.trolley
            chk = interval_check(r.stations, self._design, self._tolerances, tr.rail_spacing_m, tr.nominal_gauge_m)
            dt = time.perf_counter() - t0
            self.interval_seconds.append(dt)
            station = None if self._design is None else self._design.station
            self.screen.last_interval = (interval_summary_text(r, dt, station) + "; "
                                         + defects_text(chk, self._tolerances, station))
            self.screen.last_interval_alarm = bool(chk.defects)
            self.console.print(Text(self.screen.last_interval, style="bold red" if chk.defects else ""))
            # stored by the session's thread (the store's connection belongs to it)
            self._intervals_to_store.append((t_start, t_end, r, chk, dt, self.screen.last_interval))
        except Exception as exc:
            self.screen.last_interval = f"interval processing failed: {exc}"

    def _store_intervals(self) -> None:
        """Store the intervals processed since the last call, each in one transaction: its track
        rows as an "interval" processing run and an ``interval`` event with the run id, the seconds
        taken, the defects and the line the crew saw (a kill between the two would leave a run
        without its event, and the resume would store the interval again)."""
        from survey.session.final import track_result

        while self._intervals_to_store:
            t_start, t_end, r, chk, dt, text = self._intervals_to_store.pop(0)
            self.store.add_interval(self.rec.session_id, t_start, t_end, track_result(r.stations),
                                    {"seconds": dt, "defects": len(chk.defects), "tolerances": self._tolerances.name,
                                     "summary": text})

    def _summary_closed_by(self, fix: FixRecord, before: FixRecord | None) -> dict | None:
        """The stored summary (:meth:`survey.store.ProjectStore.interval_summaries`) of the interval
        from the accepted fix ``before`` to ``fix``; None when there is none (no fix before, live
        processing off, or it failed)."""
        if before is None:
            return None
        key = _interval_key(before.t_s, fix.t_s)
        found = [d for d in self.store.interval_summaries(self.rec.session_id)
                 if _interval_key(d["t_start_s"], d["t_end_s"]) == key]
        return found[-1] if found else None

    def _replay_live(self) -> None:
        """On resume: the stored accepted fixes into the live processor, each once the data up to
        it are in (:meth:`_replay_due`). The fixes of the static alignment are added when the
        processor is made."""
        lp = self._live_processor()
        if lp is None:
            return
        self._live_replay = [f for f in self.accepted_fixes if f.t_s > self._live_fed_t]
        # the intervals whose summary is stored; one the kill interrupted (its closing fix stored,
        # its summary not yet) is summarised again as its fix is replayed (bug hunt 2026-11-26:
        # it was lost, neither shown before the kill nor after the resume)
        # (a summary withdrawn by an undo is not one: the fix taken again at the same stop, in the
        # same simulated instant, closes an interval with the same times, which is summarised)
        self._summarised = {_interval_key(d["t_start_s"], d["t_end_s"])
                            for d in self.store.interval_summaries(self.rec.session_id)}
        self._replay_due()

    def _replay_due(self) -> None:
        """Replay the stored fixes whose data have arrived. After a crash the last fixes can be
        newer than the data stored (committed every 0.5 s, the fixes at once): fed before their
        data, a fix would anchor the live filter at the wrong place, and every later fix would fail
        the innovation test. The data come again from the devices after the resume."""
        lp = self._live if self._live not in (None, False) else None
        pending = self._live_replay
        if lp is None or not pending:
            return
        try:
            while pending and self.data_time() >= pending[0].t_s - DATA_SLACK_S:
                f = pending.pop(0)
                if self._live_thread is not None:
                    self._live_thread.join()   # the processor is not changed under a smoothing
                self._feed_live(f.t_s)
                self._add_fix(lp, f, force_accept=True)
                times = lp.fixes.t_s
                if times.size >= 2 and _interval_key(times[-2], f.t_s) not in self._summarised:
                    # here, not on the interval thread: the next replayed fix changes the processor
                    self._summarise_interval(lp, float(times[-2]), f.t_s)
        except Exception as exc:
            self.console.print(f"[yellow]live processing unavailable after resume: {escape(str(exc))}[/]")
            self._live = False


def _interval_key(t_start_s: float, t_end_s: float) -> tuple[float, float]:
    """An interval by its fixes' times (a repeated fix at a stop closes one of no length, which
    ends at the same time as the one before it)."""
    return round(float(t_start_s), 6), round(float(t_end_s), 6)


def interval_summary_text(r, seconds: float, station=None) -> str:
    """One line for the crew about the interval just smoothed: deviations, sigma, gauge and cant
    min..max (mm), seconds taken; its ends at the drawing's stations ``station(chainage)`` when
    given (the design's station equations), else at the internal chainage."""
    mm = 1e3
    ends = r.stations.chainage_m[[0, -1]]
    if station is not None:
        ends = station(ends)
    return (f"interval {ends[0]:.1f}-{ends[1]:.1f} m: max |lateral| "
            f"{mm * r.max_abs_lateral_dev_m:.2f} mm, max |vertical| {mm * r.max_abs_vertical_dev_m:.2f} mm, "
            f"max 1-sigma {mm * r.max_sigma_m:.2f} mm, gauge {mm * r.gauge_range_m[0]:.2f}..{mm * r.gauge_range_m[1]:.2f} mm, "
            f"cant {mm * r.cant_range_m[0]:.2f}..{mm * r.cant_range_m[1]:.2f} mm ({seconds:.2f} s)")


def budget_case(meta):
    """The budget case (``trolley.budget``) of a session's IMU, odometer and fix figures."""
    from trolley.budget import SensorFigures, resolve_case

    key = id(meta)
    hit = _BUDGET_CACHE.get(key)
    if hit is not None and hit[0] is meta:
        return hit[1]
    imu = meta.imu
    fig = SensorFigures(gyro_arw_rad_sqrt_s=imu.gyro_arw_rad_sqrt_s,
                        gyro_bias_instability_rad_s=imu.gyro_bias_instability_rad_s,
                        heading_error_rad=None if imu.gyrocompassing else math.radians(0.5),
                        fix_sigma_m=meta.fix_sigma_m, latitude_rad=meta.latitude_rad,
                        gyrocompassing=imu.gyrocompassing)
    case = resolve_case(fig).case
    _BUDGET_CACHE[key] = (meta, case)
    return case


def predicted_sigma_mm(meta, distance_since_fix_m: float, seconds_since_fix: float) -> float:
    """Predicted 1-sigma at the trolley's position (lateral or vertical, the larger), mm.

    The dead-reckoning sigma of the budget model after ``distance_since_fix_m`` travelled in
    ``seconds_since_fix`` (:func:`trolley.live.dead_reckoning_sigma`): what the position is known to
    now, before the next fix. It grows with the distance, also past the planned fix spacing.
    NaN when the figures do not give a budget (e.g. a custom IMU without its figures).
    """
    from trolley.live import dead_reckoning_sigma

    try:
        s = dead_reckoning_sigma(budget_case(meta), distance_since_fix_m, seconds_since_fix)
    except (ValueError, TypeError):
        return float("nan")
    return 1e3 * max(s["lateral"], s["vertical"])


def interval_sigma_mm(meta, distance_since_fix_m: float, seconds_since_fix: float) -> float:
    """Worst smoothed 1-sigma (lateral or vertical, the larger) of the interval if the next fix is
    taken here, mm: the budget (``trolley.budget.worst_sigma``, Jiang 2017 Eq. 40/45) of an
    interval of ``distance_since_fix_m`` travelled at the mean speed since the last fix. NaN
    before the trolley has moved, or when the figures do not give a budget."""
    from dataclasses import replace

    from trolley.budget import worst_sigma

    d, t = abs(float(distance_since_fix_m)), float(seconds_since_fix)
    if d < 0.1 or not t > 0:
        return float("nan")
    try:
        case = replace(budget_case(meta), fix_spacing_m=d, speed_m_s=d / t)
        return 1e3 * max(worst_sigma(case, "lateral"), worst_sigma(case, "vertical"))
    except (ValueError, TypeError):
        return float("nan")


_BUDGET_CACHE: dict = {}
