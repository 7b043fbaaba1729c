"""What the crew reads during a field session on a design with a station equation (issue 13): the
drawing's stations (1300 back = 2300 ahead in tests/data/station_equation.xml), not the internal
chainage; the stored records keep the internal chainage."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from survey.session.fieldsession import FieldSession
from survey.session.interval import IntervalCheck, defects_text, tolerance_set
from survey.session.livefilter import interval_summary_text
from trolley.landxml import read_landxml
from trolley.tolerances import Defect

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def design():
    return read_landxml((DATA / "station_equation.xml").read_text(encoding="utf-8")).alignment


def test_screen_chainage_is_the_drawing_station(design):
    fs = SimpleNamespace(_design=design)
    assert FieldSession.shown_station(fs, 1250.0) == pytest.approx(1250.0, abs=1e-9)
    assert FieldSession.shown_station(fs, 1350.5) == pytest.approx(2350.5, abs=1e-9)
    assert np.isnan(FieldSession.shown_station(fs, float("nan")))
    assert FieldSession.shown_station(SimpleNamespace(_design=None), 1350.5) == 1350.5


def test_interval_lines_use_the_drawing_stations_and_are_plain_text(design):
    tol = tolerance_set(None)
    d = Defect("gauge deviation", "gauge_dev_m", 1380.0, 1381.25, 0.00887, 0.006, 3)
    chk = IntervalCheck(geometry=object(), defects=[d], seconds=0.1)
    line = defects_text(chk, tol, design.station)
    assert line == f"1 defects against {tol.name}: gauge deviation 2380.0-2381.2 m"
    assert "[" not in line  # stored with the interval: no rich markup in the data
    assert defects_text(chk, tol).endswith("gauge deviation 1380.0-1381.2 m")
    r = SimpleNamespace(stations=SimpleNamespace(chainage_m=np.array([1260.0, 1300.0, 1320.0])),
                        max_abs_lateral_dev_m=1e-3, max_abs_vertical_dev_m=2e-3, max_sigma_m=3e-4,
                        gauge_range_m=(-1e-3, 1e-3), cant_range_m=(0.0, 2e-3))
    assert interval_summary_text(r, 0.5, design.station).startswith("interval 1260.0-2320.0 m: ")
    assert interval_summary_text(r, 0.5).startswith("interval 1260.0-1320.0 m: ")
