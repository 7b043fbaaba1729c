"""track.csv: the fast writer gives exactly the bytes pandas' to_csv gives (FORMATS.md sec. 2)."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from survey.sessionio import write_csv_columns
from survey.trackio import TRACK_COLUMNS, track_frame, write_track_csv

values = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64),
                   st.sampled_from([0.0, -0.0, -4e-7, 5e-7, -5e-7, 0.5e-6, 1e15, np.nan]))


@given(arrays(np.float64, st.tuples(st.integers(0, 30), st.just(len(TRACK_COLUMNS))), elements=values))
@settings(max_examples=60, deadline=None)
def test_fast_csv_writer_gives_the_bytes_of_pandas(tmp_path_factory, table):
    tmp = tmp_path_factory.mktemp("csv")
    frame = pd.DataFrame(table, columns=TRACK_COLUMNS)
    frame.to_csv(tmp / "pandas.csv", index=False, float_format="%.6f", na_rep="")
    write_csv_columns(tmp / "fast.csv", TRACK_COLUMNS, list(table.T), ["%.6f"] * len(TRACK_COLUMNS),
                      chunk=7, nan_as_empty=True)
    assert (tmp / "fast.csv").read_bytes() == (tmp / "pandas.csv").read_bytes()


def test_track_csv_of_a_result_is_what_pandas_writes(tmp_path):
    rng = np.random.default_rng(1)
    n = 50
    cols = {c: rng.normal(0, 1e3, n) for c in ("E_m", "N_m", "H_m", "sigma_E_m", "sigma_N_m", "sigma_H_m",
                                              "lateral_dev_m", "vertical_dev_m", "gauge_m", "cant_m", "twist_m",
                                              "cov_EN_m2", "sigma_cant_m")}
    cols["gauge_m"][10:20] = np.nan  # a sensor gap
    stations = type("S", (), dict(chainage_m=np.arange(n) * 0.625, **cols))()
    result = type("R", (), dict(stations=stations))()
    write_track_csv(tmp_path / "track.csv", result)
    track_frame(result).to_csv(tmp_path / "p.csv", index=False, float_format="%.6f", na_rep="")
    assert (tmp_path / "track.csv").read_bytes() == (tmp_path / "p.csv").read_bytes()
    back = pd.read_csv(tmp_path / "track.csv")
    assert back["gauge_mm"].isna().sum() == 10


def test_text_columns_cannot_lose_their_nan():
    with pytest.raises(ValueError, match="numeric"):
        write_csv_columns("unused.csv", ["a"], [["nan"]], ["%s"], nan_as_empty=True)
