"""Left and right rail alignment and level from the centre line (trolley.trackgeometry.rail_values):
hand-computed, in both sign conventions."""
from __future__ import annotations

import numpy as np
import pytest

from trolley.trackgeometry import GeometryConfig, TrackGeometry, rail_values


def _geometry(config):
    cols = {"lateral_dev_m": np.array([0.002, 0.0]), "vertical_dev_m": np.array([-0.001, 0.0]),
            "gauge_dev_m": np.array([0.004, np.nan]), "cant_dev_m": np.array([0.006, 0.002])}
    return TrackGeometry(chainage_m=np.array([0.0, 1.0]), step_m=1.0, columns=cols, config=config)


def test_rails_default_conventions():
    # lateral +right 2 mm, gauge 4 mm wide: left rail 2 mm further left (0 mm), right rail 4 mm right;
    # vertical -1 mm, left rail 6 mm higher than designed relative to the right: +2 / -4 mm
    r = rail_values(_geometry(GeometryConfig()))
    assert r.left_alignment_m[0] == pytest.approx(0.000) and r.right_alignment_m[0] == pytest.approx(0.004)
    assert r.left_level_m[0] == pytest.approx(0.002) and r.right_level_m[0] == pytest.approx(-0.004)
    assert np.isnan(r.left_alignment_m[1]) and r.left_level_m[1] == pytest.approx(0.001)


def test_rails_other_conventions():
    # lateral + to the left: the left rail (further out to the left) gets + g/2; cant + right high:
    # the same numbers describe the right rail higher
    r = rail_values(_geometry(GeometryConfig(lateral_sign="left", cant_sign="right_high")))
    assert r.left_alignment_m[0] == pytest.approx(0.004) and r.right_alignment_m[0] == pytest.approx(0.000)
    assert r.left_level_m[0] == pytest.approx(-0.004) and r.right_level_m[0] == pytest.approx(0.002)
