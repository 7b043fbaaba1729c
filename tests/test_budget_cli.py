"""`trolley budget`: JSON schema, consistency with trolley.budget, plots, bad input and exit codes."""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from survey.cli import app
from trolley import budget as B
from trolley import units

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, ["budget", *args])


def _json(*args):
    res = _run(*args, "--json")
    assert "Traceback" not in res.output
    return res, json.loads(res.stdout)


def test_json_schema_and_values_for_the_rlg():
    res, out = _json()
    assert res.exit_code == 0
    for d in ("vertical", "lateral", "longitudinal"):
        assert set(out[d]) >= {"mid_mm", "max_mm", "pass", "margin_mm", "sources_mid_mm", "sources_max_mm"}
        assert out[d]["max_mm"] >= out[d]["mid_mm"] > 0
        # the breakdown adds up in quadrature
        assert np.sqrt(sum(x**2 for x in out[d]["sources_max_mm"].values())) == pytest.approx(out[d]["max_mm"], rel=1e-9)
    lim = out["limits"]
    assert set(lim["max_gyro_bias_deg_h"]) == {"lateral", "vertical"}
    assert set(lim["max_gyro_arw_deg_sqrt_h"]) == {"lateral", "vertical"}
    assert lim["max_odo_scale_noise_per_sqrt_s"] == pytest.approx(1.1e-5, rel=0.03)
    assert lim["max_fix_spacing_m"] > 60
    assert out["pass"] is True
    inp = out["inputs"]
    assert inp["imu"] == "rlg" and inp["gyro_bias_route"] == "derived"
    assert inp["gyro_bias_instability_deg_h"] == pytest.approx(0.03)
    # derived route at 30 deg with a gyrocompassing heading: equivalent = 2 x bias instability
    assert inp["equivalent_gyro_bias_deg_h"] == pytest.approx(0.06, rel=1e-9)
    assert inp["equivalent_gyro_bias_rad_s"] == pytest.approx(units.deg_h_to_rad_s(0.06), rel=1e-9)
    assert inp["heading_error_source"] == "gyrocompassing"
    # the same numbers straight from the library
    r = B.resolve_case(B.SensorFigures(units.deg_sqrt_h_to_rad_sqrt_s(0.005),
                                       gyro_bias_instability_rad_s=units.deg_h_to_rad_s(0.03)))
    assert out["lateral"]["max_mm"] == pytest.approx(B.worst_sigma(r.case, "lateral") * 1e3, rel=1e-12)


def test_fog_fails_lateral_with_exit_code_1_and_limits_explain_why():
    res, out = _json("--imu", "fog", "--heading-error-deg", "0.6")
    assert res.exit_code == 1
    assert out["pass"] is False and out["lateral"]["pass"] is False
    assert out["lateral"]["max_mm"] > 0.67 and out["lateral"]["margin_mm"] < 0
    assert out["inputs"]["equivalent_gyro_bias_deg_h"] > out["limits"]["max_gyro_bias_deg_h"]["lateral"]


def test_equivalent_bias_route_is_used_as_given_and_echoed():
    res, out = _json("--gyro-bias-deg-h", "0.25", "--gyro-arw-deg-sqrt-h", "0.007", "--heading-error-deg", "0.6")
    assert out["inputs"]["imu"] == "custom"
    assert out["inputs"]["gyro_bias_route"] == "given"
    assert out["inputs"]["equivalent_gyro_bias_deg_h"] == pytest.approx(0.25)
    assert out["inputs"]["gyro_bias_instability_deg_h"] is None


def test_table_output_has_verdicts_and_limits():
    res = _run("--imu", "fog", "--heading-error-deg", "0.6")
    assert res.exit_code == 1
    for word in ("vertical", "lateral", "longitudinal", "PASS", "FAIL", "Sizing limits", "equivalent gyro bias"):
        assert word in res.stdout


@pytest.mark.parametrize("args, message", [
    (["--gyro-bias-deg-h", "-0.1", "--gyro-arw-deg-sqrt-h", "0.005"], "--gyro-bias-deg-h: must be >= 0, got -0.1"),
    (["--speed-m-s", "0"], "--speed-m-s: must be >= 0.01, got 0"),
    (["--fix-spacing-m", "-5"], "--fix-spacing-m: must be >= 1, got -5"),
    (["--target-mm", "0.3"], "cannot be met by any IMU"),
    (["--gyro-bias-deg-h", "0.1", "--gyro-bias-instability-deg-h", "0.1"], "not both"),
    (["--imu", "mems"], "--imu mems cannot find north by gyrocompassing: give --heading-error-deg"),
    (["--imu", "custom", "--gyro-arw-deg-sqrt-h", "0.005"], "--imu custom needs"),
    (["--latitude-deg", "90"], "--latitude-deg"),
    (["--monte-carlo", "-3"], "error: --monte-carlo: must be >= 0, got -3\n"),
    (["--monte-carlo", "1"], "error: --monte-carlo: must be 0 (none) or >= 2, got 1 (one run has no spread)\n"),
    (["--odo-scale-noise", "nan"], "--odo-scale-noise: must be a finite number, got nan"),
    (["--monte-carlo", "10", "--seed", "-1"], "--seed: must be >= 0"),
])
def test_bad_input_exits_2_with_one_line_and_no_output(args, message):
    res = _run(*args, "--json")
    assert res.exit_code == 2
    assert res.stdout == ""
    assert message in res.stderr
    assert "Traceback" not in res.output
    assert len(res.stderr.strip().splitlines()) == 1


def test_unknown_imu_is_refused_by_the_choices():
    res = _run("--imu", "gyroscope", "--json")
    assert res.exit_code == 2 and res.stdout == ""
    assert "'gyroscope' is not one of 'rlg', 'fog', 'mems', 'custom'" in res.stderr
    assert "Traceback" not in res.output


def test_non_numeric_figure_is_a_usage_error_not_a_traceback():
    res = _run("--gyro-arw-deg-sqrt-h", "abc", "--json")
    assert res.exit_code == 2
    assert res.stdout == ""
    assert "Traceback" not in res.output


def test_plot_writes_pngs_and_csvs_and_json_stays_clean(tmp_path):
    folder = tmp_path / "plots"
    res, out = _json("--imu", "fog", "--heading-error-deg", "0.6", "--plot", str(folder))
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["budget_requirements.csv", "budget_requirements.png", "budget_sigma.csv", "budget_sigma.png"]
    for png in ("budget_sigma.png", "budget_requirements.png"):
        assert (folder / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    sig = np.genfromtxt(folder / "budget_sigma.csv", delimiter=",", names=True)
    assert sig["lateral_mm"].max() == pytest.approx(out["lateral"]["max_mm"], rel=1e-4)
    req = np.genfromtxt(folder / "budget_requirements.csv", delimiter=",", names=True)
    # the curve at this IMU's ARW passes through the tabulated lateral bias limit
    y = np.interp(0.007, req["gyro_arw_deg_sqrt_h"], req["max_gyro_bias_lateral_deg_h"])
    assert y == pytest.approx(out["limits"]["max_gyro_bias_deg_h"]["lateral"], rel=1e-3)


def test_plot_into_a_file_is_refused(tmp_path):
    f = tmp_path / "x"
    f.write_text("")
    res = _run("--plot", str(f))
    assert res.exit_code == 2 and "not a folder" in res.stderr


def test_monte_carlo_in_json_agrees_with_sigma():
    res, out = _json("--imu", "fog", "--heading-error-deg", "0.6", "--monte-carlo", "3000", "--seed", "7")
    mc = out["monte_carlo"]
    assert mc["runs"] == 3000
    tol = 4.5 * mc["relative_sampling_error"]
    for d in ("vertical", "lateral", "longitudinal"):
        assert mc[d]["mid_sigma_mm"] == pytest.approx(out[d]["mid_mm"], rel=1e-12)
        assert abs(mc[d]["mid_rms_mm"] / mc[d]["mid_sigma_mm"] - 1) < tol
        assert abs(mc[d]["worst_rms_mm"] / mc[d]["worst_sigma_mm"] - 1) < tol


def test_mems_limits_are_null_with_a_reason():
    res, out = _json("--imu", "mems", "--heading-error-deg", "0.5")
    assert res.exit_code == 1 and out["pass"] is False
    assert out["limits"]["max_gyro_bias_deg_h"]["lateral"] is None
    assert "no equivalent gyro bias meets the lateral target" in out["limit_notes"]["max_gyro_bias_deg_h.lateral"]
    # the fix spacing that would make it pass is still given, and it does pass there
    spacing = out["limits"]["max_fix_spacing_m"]
    res2, out2 = _json("--imu", "mems", "--heading-error-deg", "0.5", "--fix-spacing-m", f"{spacing * 0.999:.6f}")
    assert res2.exit_code == 0 and out2["pass"] is True


@pytest.mark.parametrize("route", [[], ["--heading-error-deg", "0.3"]], ids=["gyrocompassing", "given-heading"])
@pytest.mark.parametrize("imu", ["rlg", "fog"])
def test_bias_instability_limit_fed_back_gives_the_target(route, imu):
    res, out = _json("--imu", imu, *route)
    lim = out["limits"]["max_gyro_bias_instability_deg_h"]
    for d in ("lateral", "vertical"):
        res2, out2 = _json("--imu", imu, *route, "--gyro-bias-instability-deg-h", repr(lim[d]))
        assert out2[d]["max_mm"] == pytest.approx(0.67, rel=1e-6), (d, out2[d]["max_mm"])
        assert out2["inputs"]["gyro_bias_route"] == "derived"
    eq = out["limits"]["max_gyro_bias_deg_h"]
    if route:
        # heading held: the equivalent bias is BI + omega_ie cos(L) |H|, so the old subtraction holds
        term = units.rad_s_to_deg_h(units.EARTH_RATE_RAD_S * np.cos(np.deg2rad(30.0)) * np.deg2rad(0.3))
        for d in ("lateral", "vertical"):
            assert lim[d] == pytest.approx(eq[d] - term, rel=1e-8)
    else:
        # gyrocompassing: equivalent bias = 2 BI; the vertical channel does not see the heading, so
        # its limit is exactly half the equivalent-bias limit; the lateral one, whose heading error
        # grows with it too, is no higher
        assert lim["vertical"] == pytest.approx(eq["vertical"] / 2, rel=1e-8)
        assert lim["lateral"] <= eq["lateral"] / 2 * (1 + 1e-9)


def test_rlg_bias_instability_limit_is_the_re_derived_one():
    # the audit's example: equivalent-bias limit minus the Earth-rate term at the current heading
    # (0.2035 deg/h) gives 0.989 mm lateral; the re-derived limit is about 0.117 deg/h
    res, out = _json()
    bi = out["limits"]["max_gyro_bias_instability_deg_h"]["lateral"]
    assert bi == pytest.approx(0.1167, abs=5e-4)
    wrong = out["limits"]["max_gyro_bias_deg_h"]["lateral"] - out["inputs"]["earth_rate_heading_term_deg_h"]
    res2, out2 = _json("--gyro-bias-instability-deg-h", repr(wrong))
    assert out2["lateral"]["max_mm"] > 0.9 and res2.exit_code == 1


def test_table_shows_contributions_at_mid_interval_and_at_the_worst_point():
    res, out = _json()
    assert out["lateral"]["worst_at_m"] == pytest.approx(60.0)  # a good IMU: worst point at the fix
    table = _run().stdout
    mid = table[table.index("Contributions at MID-INTERVAL"):table.index("Contributions at the WORST POINT")]
    worst = table[table.index("Contributions at the WORST POINT"):table.index("Sizing limits")]
    row = lambda block, label: block[block.index(label):].splitlines()[0]  # noqa: E731
    # at mid-interval the gyro terms show (0.129, 0.131 mm); at the fix they vanish (0.007, 0.000)
    for d, col in (("vertical", 1), ("lateral", 2)):
        for block, key in ((mid, "sources_mid_mm"), (worst, "sources_max_mm")):
            cells = [c.strip() for c in row(block, "equivalent gyro bias").split("│") if c.strip()]
            assert cells[col] == f"{out[d][key]['gyro_bias']:.3f}"
    assert out["lateral"]["sources_mid_mm"]["gyro_bias"] > 0.1
    assert f"{out['lateral']['sources_max_mm']['gyro_bias']:.3f}" == "0.000"


def test_odometer_defaults_come_from_one_place():
    from trolley.sensors import OdometerFigures

    res, out = _json()
    assert out["inputs"]["odo_scale_noise_per_sqrt_s"] == OdometerFigures().scale_noise_per_sqrt_s
    assert out["inputs"]["odo_scale_error"] == B.BUDGET_ODO_SCALE_ERROR
    # given explicitly, they are used
    res, out = _json("--odo-scale-error", "1e-4", "--odo-scale-noise", "9e-6")
    assert out["inputs"]["odo_scale_error"] == 1e-4 and out["inputs"]["odo_scale_noise_per_sqrt_s"] == 9e-6
    assert out["limits"]["max_odo_scale_noise_per_sqrt_s"] < 0.8e-5  # a residual scale error lowers the limit


def test_seed_must_be_non_negative():
    res = _run("--monte-carlo", "10", "--seed", "-1", "--json")
    assert res.exit_code == 2 and res.stdout == ""
    assert "--seed: must be >= 0, got -1" in res.stderr


def test_out_of_memory_is_a_clear_exit_2(monkeypatch):
    def no_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(B, "monte_carlo", no_memory)
    res = _run("--monte-carlo", "20000", "--fix-spacing-m", "1000", "--json")
    assert res.exit_code == 2 and res.stdout == ""
    assert "not enough memory" in res.stderr and "--monte-carlo" in res.stderr
    assert "Traceback" not in res.output


#: the reason the range messages give (survey.limits.check_finite's why=)
MODEL = "(the range of the error model)"


@pytest.mark.parametrize("args, message", [
    (["--gyro-bias-deg-h", "1e300", "--gyro-arw-deg-sqrt-h", "0.005"],
     "--gyro-bias-deg-h: must be <= 1000, got 1e+300 " + MODEL),
    (["--level-error-deg", "1e5"], "--level-error-deg: must be <= 10, got 100000 " + MODEL),
    (["--fix-spacing-m", "1e-9", "--monte-carlo", "2"], "--fix-spacing-m: must be >= 1, got 1e-09 " + MODEL),
    (["--fix-spacing-m", "1e300", "--monte-carlo", "10"],
     "--fix-spacing-m: must be <= 10000, got 1e+300 " + MODEL),
    (["--speed-m-s", "1e11"], "--speed-m-s: must be <= 30, got 1e+11 " + MODEL),
    # (the colon after the option was missing, and this test pinned it so)
    (["--monte-carlo", "99999999999"],
     "error: --monte-carlo: must be <= 1000000, got 99999999999 (their RMS then has a 0.07 % sampling error)\n"),
    # all the digits: "%g" showed 89.999999 as 90
    (["--latitude-deg", "89.999999"],
     "--latitude-deg: must be <= 85, got 89.999999 (no gyrocompassing near the poles)"),
    (["--imu", "custom", "--gyro-bias-instability-deg-h", "3", "--gyro-arw-deg-sqrt-h", "0.15"],
     "gyrocompasses to a heading error of 13.2 deg"),
])
def test_inputs_beyond_the_error_models_range_are_refused(args, message):
    # (a bug hunt: they gave ZeroDivisionError, "Python int too large", NaN sigmas, or sigmas that
    # shrank as the error grew, some reported as PASS)
    res = _run(*args, "--json")
    assert res.exit_code == 2 and res.stdout == "" and message in res.stderr, res.output


def test_the_worst_point_grows_with_every_error_across_the_accepted_ranges():
    # within the ranges the CLI accepts the sigmas are monotone in each error source (the bug hunt
    # found 1e6 -> 1.39 mm, 1e7 -> 0.67 mm, 1e15 -> 0.59 mm of vertical sigma far outside them)
    import numpy as np

    from trolley import budget as B
    from trolley import units

    def worst(**kw):
        figs = B.SensorFigures(gyro_arw_rad_sqrt_s=units.deg_sqrt_h_to_rad_sqrt_s(0.005),
                               heading_error_rad=units.deg_to_rad(0.5), **kw)
        res = B.budget(B.resolve_case(figs).case)
        return np.array([res[d].max_sigma_m for d in B.DIRECTIONS])

    for name, values in (("equivalent_gyro_bias_rad_s", units.deg_h_to_rad_s(np.logspace(-3, 3, 13))),
                         ("level_error_rad", units.deg_to_rad(np.linspace(0.0, 10.0, 11)))):
        extra = {} if name == "equivalent_gyro_bias_rad_s" else {"equivalent_gyro_bias_rad_s": 1e-7}
        w = np.array([worst(**{name: v}, **extra) for v in values])
        assert np.all(np.isfinite(w))
        assert np.all(np.diff(w, axis=0) >= -1e-12 * w[1:]), (name, w)


def test_the_fixes_are_worst_points_too_when_the_bias_drift_dwarfs_the_fix_sigma():
    # ARW, level and heading errors zero, 200 deg/h over 10 km: the fix at T absorbs the bias and
    # the worst sigma is the fixes' own 0.6 mm (a cancelling grid had said 0.480 mm at 8750 m, PASS)
    res, out = _json("--gyro-bias-deg-h", "200", "--gyro-arw-deg-sqrt-h", "0", "--heading-error-deg", "0",
                     "--level-error-deg", "0", "--odo-scale-noise", "0", "--fix-spacing-m", "10000",
                     "--target-mm", "0.5")
    assert res.exit_code == 1 and out["pass"] is False
    for d in ("vertical", "lateral"):
        assert out[d]["max_mm"] == pytest.approx(0.6, rel=1e-9)
        assert out[d]["worst_at_m"] in (0.0, 10000.0)


def test_limits_fed_back_pass_and_unbounded_ones_are_told_from_none_meets():
    res, out = _json()
    lim = out["limits"]
    for args, d in ((["--fix-spacing-m", repr(lim["max_fix_spacing_m_by_direction"]["longitudinal"])], "longitudinal"),
                    (["--odo-scale-noise", repr(lim["max_odo_scale_noise_per_sqrt_s"])], "longitudinal"),
                    (["--gyro-arw-deg-sqrt-h", repr(lim["max_gyro_arw_deg_sqrt_h"]["vertical"])], "vertical")):
        _, back = _json(*args)
        assert back[d]["pass"] is True and back[d]["max_mm"] == pytest.approx(0.67, rel=1e-9), args
    res, out = _json("--odo-scale-noise", "0", "--target-mm", "0.8", "--fix-spacing-m", "10")
    assert out["limits"]["max_fix_spacing_m_by_direction"]["longitudinal"] is None
    assert "max_fix_spacing_m.longitudinal" in out["limits_unbounded"]
    assert "max_gyro_bias_deg_h.vertical" in out["limits_unbounded"]
    table = _run("--odo-scale-noise", "0", "--target-mm", "0.8", "--fix-spacing-m", "10").output
    assert "any to the cap" in table and "none meets" not in table
    _, low = _json("--target-mm", "0.5", "--level-error-deg", "0")
    assert low["limits"]["max_fix_spacing_m_by_direction"]["lateral"] < 1.0
    assert "below the 1 m this budget models" in low["limit_notes"]["max_fix_spacing_m.lateral"]
    assert "max_gyro_bias_deg_h.lateral" not in low["limits_unbounded"]

