"""The prism constant through a real pty: the twin's physical prism and configured correction, the
client's set / read-back / switch-only-when-needed, and a refused or ignored set.

Leica's convention (drivers/geocom.py LEICA_PRISM_CONSTANT_M): the instrument adds its configured
constant to what its EDM measured, and the EDM alone reads a prism of constant c that much short,
so the reported slope distance is ``geometric + configured - c``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers import geocom as gc
from drivers.totalstation import PrismConstantError, TotalStation
from drivers.twins.totalstation import TotalStationTwin

STATION = (1000.0, 2000.0, 50.0, 1.55)
TARGET = (1012.0, 2030.0, 50.8)
GRZ4 = 0.0231  # Leica 360° prism


def _pair(twin: TotalStationTwin) -> TotalStation:
    ts = TotalStation(twin.port, timeout_s=2.0, long_timeout_s=2.0)
    ts.link.open()
    twin.start()
    ts.connect()
    return ts


def _geometric() -> float:
    e0, n0, h0, hi = STATION
    return math.dist((e0, n0, h0 + hi), TARGET)


def _sent(twin: TotalStationTwin, rpc: int) -> int:
    return sum(r.rpc == rpc for r in twin.requests)


def test_360_prism_right_only_with_its_constant_and_switched_only_when_needed():
    twin = TotalStationTwin(STATION, TARGET, target_constant_m=GRZ4)  # instrument at its factory 0.0
    ts = _pair(twin)
    try:
        ts.fine_adjust()
        wrong = ts.measure()
        assert ts.ensure_prism_constant(GRZ4) == pytest.approx(GRZ4, abs=1e-12)
        right = ts.measure()
        hz, v, sd_bap = ts.meas_distance_angle()
        sets = _sent(twin, gc.TMC_SETPRISMCORR), _sent(twin, gc.TMC_GETPRISMCORR)
        ts.ensure_prism_constant(GRZ4)  # already set and read back: nothing sent
        unchanged = _sent(twin, gc.TMC_SETPRISMCORR), _sent(twin, gc.TMC_GETPRISMCORR)
        ts.ensure_prism_constant(0.0)  # the CPIII round prisms: one set and one read back
        switched = _sent(twin, gc.TMC_SETPRISMCORR), _sent(twin, gc.TMC_GETPRISMCORR)
        # BAP_SetPrismType selects a type's Leica constant (mini prism +17.5 mm); an unlisted type is refused
        ts.call(gc.BAP_SETPRISMTYPE, (gc.BAP_PRISM_MINI,))
        mini = ts.prism_constant()
        with pytest.raises(gc.GeoComError) as refused:
            ts.call(gc.BAP_SETPRISMTYPE, (9,))
    finally:
        ts.close()
        twin.stop()
    # by hand: 23.1 mm short along the line of sight without the constant, exact with it
    assert wrong.slope_m == pytest.approx(_geometric() - 0.0231, abs=1e-9)
    assert math.dist((wrong.E_m, wrong.N_m, wrong.H_m), TARGET) == pytest.approx(0.0231, abs=1e-9)
    assert right.slope_m == pytest.approx(_geometric(), abs=1e-9) and sd_bap == pytest.approx(_geometric(), abs=1e-9)
    assert (right.E_m, right.N_m, right.H_m) == pytest.approx(TARGET, abs=1e-9)
    assert sets == (1, 1) and unchanged == sets and switched == (2, 2)
    assert mini == pytest.approx(0.0175, abs=1e-12) and refused.value.code == 2


class IgnoringStation(TotalStationTwin):
    """An instrument that answers TMC_SetPrismCorr with OK and keeps its own constant (while ``ignore``)."""

    ignore = True

    def handle(self, req):
        if self.ignore and req.rpc == gc.TMC_SETPRISMCORR:
            return 0, ()
        return super().handle(req)


def test_an_ignored_or_refused_set_is_caught_by_the_read_back():
    twin = IgnoringStation(STATION, TARGET, prism_corr_m=0.0)
    ts = _pair(twin)
    try:
        with pytest.raises(PrismConstantError) as ignored:
            ts.ensure_prism_constant(GRZ4)
        # firmware without TMC_SetPrismCorr (3081): the constant set on the keyboard passes the read-back
        twin.ignore, twin.prism_corr_m = False, GRZ4
        twin.inject_rc(3081, rpc=gc.TMC_SETPRISMCORR)
        held = ts.ensure_prism_constant(GRZ4)
        twin.inject_rc(3081, rpc=gc.TMC_SETPRISMCORR)
        with pytest.raises(PrismConstantError) as refused:
            ts.ensure_prism_constant(0.0)
    finally:
        ts.close()
        twin.stop()
    text = str(ignored.value)
    assert twin.port in text and "+0.00 mm on the instrument, +23.10 mm expected" in text
    assert ignored.value.set_error is None and held == pytest.approx(GRZ4)
    assert refused.value.set_error is not None and refused.value.set_error.code == 3081
    assert "+23.10 mm on the instrument, +0.00 mm expected" in str(refused.value) and "3081" in str(refused.value)
    assert ts.verified_prism_constant_m is None  # not trusted after a mismatch: the next call asks again
    assert np.isfinite(held)


class RestartingStation(TotalStationTwin):
    """An instrument that comes back from a power cycle with its factory constant (the round prism)."""

    def power_up(self) -> None:
        self.prism_corr_m = 0.0


def test_the_constant_is_set_again_after_the_instrument_came_back():
    # the port vanished and came back (a battery changed, a cable pulled): the client trusted the
    # constant it had set before and measured the 360° prism 23.1 mm short
    twin = RestartingStation(STATION, TARGET, target_constant_m=GRZ4)
    ts = _pair(twin)
    try:
        ts.ensure_prism_constant(GRZ4)
        twin.disappear(0.2, power_cycle=True)
        ts.null_proc()   # answers again (retried until the port is back)
        assert ts.stats.reconnects == 1
        ts.ensure_prism_constant(GRZ4)
        ts.fine_adjust()
        after_reconnect = ts.measure().slope_m
        # the session's "total station answers again" after a fault (an RS-232 port that never vanished)
        twin.power_up()
        ts.forget_prism_constant()
        ts.ensure_prism_constant(GRZ4)
        after_fault = ts.measure().slope_m
    finally:
        ts.close()
        twin.stop()
    assert after_reconnect == pytest.approx(_geometric(), abs=1e-9)
    assert after_fault == pytest.approx(_geometric(), abs=1e-9)
    assert _sent(twin, gc.TMC_SETPRISMCORR) == 3
