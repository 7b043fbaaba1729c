"""``trolley inservice process`` on what a data logger really writes (bug hunt 26b): time stamps
that jitter, a clock a few ppm off, epoch seconds, model files cut short or hand-edited."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from test_inservice_io import _app
from test_inservice_process import recording  # noqa: F401  (the fixture)
from typer.testing import CliRunner

from survey import inservice_io as io
from survey.inservice_model import BUILTIN_MODEL_PATH


def _copy(recording, tmp_path, t=None):  # noqa: F811
    """The fixture's recording with its time column replaced by ``t(t_s)``."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "inservice.toml").write_bytes((recording / "recording" / "inservice.toml").read_bytes())
    df = pd.read_csv(recording / "recording" / "sensors.csv")
    if t is not None:
        df["t_s"] = t(df["t_s"].to_numpy())
    df.to_csv(rec / "sensors.csv", index=False, float_format="%.17g")
    return rec


def _jitter(t):
    return t + np.random.default_rng(3).uniform(-1e-3, 1e-3, t.size)      # +-20 % of a 5 ms step


@pytest.mark.parametrize("stamps", [
    _jitter,                                   # software time stamps
    lambda t: 1.7e9 + t,                       # epoch seconds (a float64 holds them to 0.24 us)
    lambda t: t * 1.00005,                     # a clock 50 ppm fast
])
def test_jittering_time_stamps_are_read_as_the_uniform_samples_they_are(recording, tmp_path, stamps):  # noqa: F811
    # (bug hunt 26b) +-20 us of jitter at 200 Hz was refused as "a gap or a dropped sample?"; epoch
    # seconds and a clock 50 ppm off made the filter rate "differ from the calibration's" (199.995 Hz):
    # a warning of a J several times larger and no consistency check
    rec = _copy(recording, tmp_path, stamps)
    back = io.read_recording(rec)
    assert back.t_s[0] == 0.0 and np.allclose(np.diff(back.t_s), 0.005, rtol=1e-4, atol=0.0)
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out"),
                                      "--model", str(BUILTIN_MODEL_PATH)])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["consistency"]["checked"] is True, summary["consistency"]
    assert "the filter runs at" not in res.stderr


@pytest.mark.parametrize("stamps, said", [
    (lambda t: np.where(np.arange(t.size) >= 700, t + 0.005, t),
     "row 702, column t_s: a step of 0.01 s after 3.495 s where the samples are 0.005 s apart"),
    (lambda t: np.where(t > 3.75, 3.75 + (t - 3.75) * 1.2, t),
     "row 2, column t_s: 0 s is more than half a sample from the uniform rate of the whole file"),
])
def test_a_dropped_sample_or_a_rate_that_changes_is_still_refused(recording, tmp_path, stamps, said):  # noqa: F811
    rec = _copy(recording, tmp_path, stamps)
    res = CliRunner().invoke(_app(), ["inservice", "process", str(rec), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2 and said in " ".join(res.output.split()), res.output
    assert not (tmp_path / "out").exists()
