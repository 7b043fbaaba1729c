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
            self._live = LiveProcessor(self.rec.meta, self._design)
            imu = self.acq.buffers.array("imu", 7)
            t0 = self.static_start_s if self.static_start_s is not None else imu[0, 0]
            sel = (imu[:, 0] >= t0) & (imu[:, 0] <= t0 + self.rec.meta.static_s)
            self._live.align(imu[sel, 0], imu[sel, 1:4], imu[sel, 4:7])
            self._live_fed_t = float(imu[sel, 0][-1])
            for f in self.accepted_fixes:  # fixes taken during the static alignment
                if f.t_s <= self._live_fed_t:
                    self._live.add_fix(f.t_s, f.point, np.array([f.e_m, f.n_m, f.h_m]),
                                       np.array([f.sigma_e_m, f.sigma_n_m, f.sigma_h_m]), force_accept=True)
        return self._live

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
            self._feed_live(fix.t_s)
            return lp.add_fix(fix.t_s, fix.point, np.array([fix.e_m, fix.n_m, fix.h_m]),
                              np.array([fix.sigma_e_m, fix.sigma_n_m, fix.sigma_h_m]))
        except Exception as exc:  # never stop the survey for the live view
            self.console.print(f"[yellow]live processing unavailable: {exc}[/]", highlight=False)
            self._live = False
            return None

    def _process_interval_async(self) -> None:
        lp = self._live if self._live not in (None, False) else None
        if lp is None:
            return

        def run() -> None:
            from survey.session.interval import defects_text, interval_check, tolerance_set

            try:
                t0 = time.perf_counter()
                r = lp.smooth_last_interval()
                if self._tolerances is None:
                    self._tolerances = tolerance_set(self.config.tolerances or self.settings.tolerance_set)
                tr = self.rec.meta.trolley
                chk = interval_check(r.stations, self._design, self._tolerances, tr.rail_spacing_m, tr.nominal_gauge_m)
                dt = time.perf_counter() - t0
                self.interval_seconds.append(dt)
                self.screen.last_interval = interval_summary_text(r, dt) + "; " + defects_text(chk, self._tolerances)
                self.console.print(self.screen.last_interval, highlight=False)
            except Exception as exc:
                self.screen.last_interval = f"interval processing failed: {exc}"

        if self._live_thread is not None:
            self._live_thread.join()
        self._live_thread = threading.Thread(target=run, name="interval", daemon=True)
        self._live_thread.start()

    def _replay_live(self) -> None:
        lp = self._live_processor()
        if lp is None:
            return
        try:
            for f in self.accepted_fixes:
                self._feed_live(f.t_s)
                lp.add_fix(f.t_s, f.point, np.array([f.e_m, f.n_m, f.h_m]),
                           np.array([f.sigma_e_m, f.sigma_n_m, f.sigma_h_m]), force_accept=True)
        except Exception as exc:
            self.console.print(f"[yellow]live processing unavailable after resume: {exc}[/]")
            self._live = False

def interval_summary_text(r, seconds: float) -> str:
    """One line for the crew about the interval just smoothed."""
    mm = 1e3
    return (f"interval {r.stations.chainage_m[0]:.1f}-{r.stations.chainage_m[-1]:.1f} m: max |lateral| "
            f"{mm * r.max_abs_lateral_dev_m:.2f} mm, max |vertical| {mm * r.max_abs_vertical_dev_m:.2f} mm, "
            f"max 1-sigma {mm * r.max_sigma_m:.2f} mm, gauge range {mm * (r.gauge_range_m[1] - r.gauge_range_m[0]):.2f} mm, "
            f"cant range {mm * (r.cant_range_m[1] - r.cant_range_m[0]):.2f} mm ({seconds:.2f} s)")


def predicted_sigma_mm(meta, distance_since_fix_m: float, speed_m_s: float, spacing_m: float = 60.0) -> float:
    """Predicted smoothed 1-sigma (lateral/vertical, the larger) at the trolley's position.

    Budget model ``trolley.budget`` (Jiang 2017 Sec. 4) for an interval of ``spacing_m`` travelled at the
    nominal 1 m/s; the position in the interval is the distance since the last fix.
    """
    try:
        from trolley.budget import SensorFigures, resolve_case, sigma_along

        key = (id(meta), spacing_m)
        case = _BUDGET_CACHE.get(key)
        if case is None:
            imu = meta.imu
            fig = SensorFigures(gyro_arw_rad_sqrt_s=imu.gyro_arw_rad_sqrt_s,
                                gyro_bias_instability_rad_s=imu.gyro_bias_instability_rad_s,
                                heading_error_rad=None if imu.gyrocompassing else math.radians(0.5),
                                fix_spacing_m=spacing_m, speed_m_s=1.0, fix_sigma_m=meta.fix_sigma_m,
                                latitude_rad=meta.latitude_rad, gyrocompassing=imu.gyrocompassing)
            case = _BUDGET_CACHE.setdefault(key, resolve_case(fig).case)
        t = min(max(distance_since_fix_m, 0.0), spacing_m)
        s = sigma_along(case, np.array([t]))
        return 1e3 * float(max(s["lateral"][0], s["vertical"][0]))
    except Exception:
        return float("nan")


_BUDGET_CACHE: dict = {}
