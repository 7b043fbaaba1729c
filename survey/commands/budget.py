"""``trolley budget``: analytic accuracy budget of one fix interval and IMU/odometer sizing.

The science is :mod:`trolley.budget` (Jiang 2017 Sec. 5, Eq. 40/44/45 corrected); this module
reads the options (datasheet units), converts them with :mod:`trolley.units`, prints the table or
the JSON, and writes the plots. ``docs/budget.md`` explains every number.

Exit codes: 0 every direction within the target, 1 at least one direction over it, 2 bad input.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Optional

import typer

from survey import jsonout
from survey.atomicwrite import write_text_atomic, write_with
from survey.commands.options import BudgetImu, old_name, renamed
from rich.markup import escape

IMU_CHOICES = ("rlg", "fog", "mems", "custom")


class BudgetInputError(ValueError):
    """Bad command-line input: reported in one line, exit code 2."""


def _fail(msg: str) -> None:
    typer.echo("error: " + " ".join(str(msg).split()), err=True)
    raise typer.Exit(code=2)


def _num(x) -> float | None:
    """A JSON-safe float: None for nan and inf."""
    x = float(x)
    return x if math.isfinite(x) else None


#: What the budget's error model holds for, per option (datasheet units): the model is linear in
#: small angles (Jiang 2017 Eq. 6), and far outside these a value overflows or the sigmas turn NaN
#: or even shrink as an error grows. The gyro and odometer ceilings are at or above the sizing
#: searches' caps (docs/budget.md), the angles at 10 deg, the interval at 10 km.
RANGES = {
    "gyro_bias_deg_h": (0.0, 1000.0), "gyro_bias_instability_deg_h": (0.0, 1000.0),
    "gyro_arw_deg_sqrt_h": (0.0, 34.0), "heading_error_deg": (0.0, 10.0), "level_error_deg": (0.0, 10.0),
    "odo_scale_noise": (0.0, 1e-2), "odo_scale_error": (0.0, 1e-2), "fix_spacing_m": (1.0, 10000.0),
    "speed_m_s": (0.01, 30.0), "fix_sigma_mm": (1e-3, 1000.0),
}
#: largest heading error the small-angle model takes, deg (given or from gyrocompassing)
MAX_HEADING_ERROR_DEG = RANGES["heading_error_deg"][1]
#: most Monte Carlo runs (their RMS then has a 0.07 % sampling error)
MAX_MONTE_CARLO_RUNS = 1_000_000


def _check_ranges(**values) -> None:
    """The shared messages of survey.limits.check_finite (nan, inf, then the range), None = not given."""
    from survey.limits import check_finite

    for name, x in values.items():
        lo, hi = RANGES[name]
        try:
            check_finite(x, f"--{name.replace('_', '-')}", minimum=lo, maximum=hi, why="the range of the error model")
        except ValueError as exc:
            raise BudgetInputError(str(exc)) from None


def sensor_figures(imu, gyro_bias_deg_h, gyro_bias_instability_deg_h, gyro_arw_deg_sqrt_h,
                   heading_error_deg, level_error_deg, odo_scale_noise, odo_scale_error,
                   fix_spacing_m, speed_m_s, fix_sigma_mm, latitude_deg):
    """Options (datasheet units) -> (imu name, trolley.budget.SensorFigures in SI).

    A preset gives the datasheet bias instability and ARW (derived route); an explicit
    ``--gyro-bias-deg-h`` (equivalent bias, given route), ``--gyro-bias-instability-deg-h`` or
    ``--gyro-arw-deg-sqrt-h`` overrides the preset's figure. Without ``--imu`` the IMU is
    ``custom`` when both a bias and the ARW are given, else ``rlg`` (Jiang 2017 Sec. 2).
    """
    from trolley import units
    from trolley.budget import SensorFigures
    from trolley.sensors import IMU_PRESETS

    from survey.limits import check_finite
    from trolley.earth import MAX_LATITUDE_DEG

    _check_ranges(gyro_bias_deg_h=gyro_bias_deg_h, gyro_bias_instability_deg_h=gyro_bias_instability_deg_h,
                  gyro_arw_deg_sqrt_h=gyro_arw_deg_sqrt_h, heading_error_deg=heading_error_deg,
                  level_error_deg=level_error_deg, odo_scale_noise=odo_scale_noise, odo_scale_error=odo_scale_error,
                  fix_spacing_m=fix_spacing_m, speed_m_s=speed_m_s, fix_sigma_mm=fix_sigma_mm)
    try:
        check_finite(latitude_deg, "--latitude-deg", minimum=-MAX_LATITUDE_DEG, maximum=MAX_LATITUDE_DEG,
                     why="no gyrocompassing near the poles")
    except ValueError as exc:
        raise BudgetInputError(str(exc)) from None
    if gyro_bias_deg_h is not None and gyro_bias_instability_deg_h is not None:
        raise BudgetInputError("give either --gyro-bias-deg-h (equivalent bias) or "
                               "--gyro-bias-instability-deg-h (datasheet), not both")
    any_bias = gyro_bias_deg_h is not None or gyro_bias_instability_deg_h is not None
    if imu is None:
        imu = "custom" if any_bias and gyro_arw_deg_sqrt_h is not None else "rlg"
    imu = imu.lower()
    if imu not in IMU_CHOICES:
        raise BudgetInputError(f"--imu must be one of {', '.join(IMU_CHOICES)}, got {imu!r}")
    if imu == "custom":
        if gyro_arw_deg_sqrt_h is None or not any_bias:
            raise BudgetInputError("--imu custom needs --gyro-arw-deg-sqrt-h and one of --gyro-bias-deg-h "
                                   "or --gyro-bias-instability-deg-h")
        arw = units.deg_sqrt_h_to_rad_sqrt_s(gyro_arw_deg_sqrt_h)
        bi = None if gyro_bias_instability_deg_h is None else units.deg_h_to_rad_s(gyro_bias_instability_deg_h)
        gyrocompassing = True
    else:
        preset = IMU_PRESETS[imu]
        arw = (preset.gyro_arw_rad_sqrt_s if gyro_arw_deg_sqrt_h is None
               else units.deg_sqrt_h_to_rad_sqrt_s(gyro_arw_deg_sqrt_h))
        bi = (units.deg_h_to_rad_s(gyro_bias_instability_deg_h) if gyro_bias_instability_deg_h is not None
              else preset.gyro_bias_instability_rad_s)
        gyrocompassing = preset.gyrocompassing
        if not gyrocompassing and heading_error_deg is None:
            raise BudgetInputError(f"--imu {imu} cannot find north by gyrocompassing: give --heading-error-deg "
                                   "(the heading error of its alignment, e.g. from the first fixes)")
    eq = None if gyro_bias_deg_h is None else units.deg_h_to_rad_s(gyro_bias_deg_h)
    if eq is not None:
        bi = None
    # the odometer figures not given keep SensorFigures' defaults (one place: trolley.budget)
    odometer = {k: x for k, x in (("odo_scale_noise_per_sqrt_s", odo_scale_noise),
                                  ("odo_scale_error", odo_scale_error)) if x is not None}
    figs = SensorFigures(
        gyro_arw_rad_sqrt_s=arw, equivalent_gyro_bias_rad_s=eq, gyro_bias_instability_rad_s=bi,
        heading_error_rad=None if heading_error_deg is None else units.deg_to_rad(heading_error_deg),
        level_error_rad=units.deg_to_rad(level_error_deg), fix_spacing_m=fix_spacing_m, speed_m_s=speed_m_s,
        fix_sigma_m=units.mm_to_m(fix_sigma_mm), latitude_rad=units.deg_to_rad(latitude_deg),
        gyrocompassing=gyrocompassing, **odometer)
    return imu, figs


def compute_report(imu: str, figs, target_mm: float, monte_carlo_runs: int, seed: int,
                   progress=None) -> dict:
    """Everything the command prints, as one JSON-ready dict (schema in docs/budget.md).

    ``progress(step, fraction)`` follows the Monte Carlo block by block (survey/commands/progress.py).
    """
    from trolley import budget as B
    from trolley import units

    resolved = B.resolve_case(figs)
    if resolved.heading_route == "gyrocompassing" and resolved.heading_error_rad > units.deg_to_rad(MAX_HEADING_ERROR_DEG):
        raise BudgetInputError(
            f"this IMU gyrocompasses to a heading error of {units.rad_to_deg(resolved.heading_error_rad):.3g} deg at "
            f"--latitude-deg {units.rad_to_deg(figs.latitude_rad):g}, beyond the {MAX_HEADING_ERROR_DEG:g} deg the "
            "small-angle error model takes: it cannot find north by itself; give --heading-error-deg")
    case = resolved.case
    target = units.mm_to_m(target_mm)
    floor = B.perfect_imu_floor(resolved)
    for d, f in floor.items():
        if f >= target:
            raise BudgetInputError(
                f"--target-mm {target_mm:g} cannot be met by any IMU: with a perfect gyro the {d} worst point "
                f"is already {units.m_to_mm(f):.3f} mm (fix sigma, spacing and the other errors)")
    res = B.budget(case)
    out: dict = {}
    for d in B.DIRECTIONS:
        r = res[d]
        names = B.SOURCE_NAMES[d]
        out[d] = {
            "mid_mm": units.m_to_mm(r.mid_sigma_m),
            "max_mm": units.m_to_mm(r.max_sigma_m),
            "worst_at_m": r.worst_time_s * figs.speed_m_s,
            "pass": bool(r.max_sigma_m <= target),
            "margin_mm": units.m_to_mm(target - r.max_sigma_m),
            "sources_mid_mm": {names[k]: units.m_to_mm(math.sqrt(max(r.mid_sources_m2[k], 0.0))) for k in names},
            "sources_max_mm": {names[k]: units.m_to_mm(math.sqrt(max(r.max_sources_m2[k], 0.0))) for k in names},
        }
    limits, notes, unbounded = _limits(case, resolved, figs, target)
    out["limits"] = limits
    out["limit_notes"] = notes
    # which nulls of "limits" mean "any value up to the search cap meets" (the others: none does)
    out["limits_unbounded"] = unbounded
    out["pass"] = all(out[d]["pass"] for d in B.DIRECTIONS)
    heading_term = (units.EARTH_RATE_RAD_S * math.cos(figs.latitude_rad) * abs(resolved.heading_error_rad))
    out["inputs"] = {
        "imu": imu,
        "gyro_bias_route": resolved.bias_route,
        "equivalent_gyro_bias_deg_h": units.rad_s_to_deg_h(resolved.equivalent_gyro_bias_rad_s),
        "equivalent_gyro_bias_rad_s": resolved.equivalent_gyro_bias_rad_s,
        "gyro_bias_instability_deg_h": (None if figs.gyro_bias_instability_rad_s is None
                                        else units.rad_s_to_deg_h(figs.gyro_bias_instability_rad_s)),
        "earth_rate_heading_term_deg_h": (units.rad_s_to_deg_h(heading_term)
                                          if resolved.bias_route == "derived" else 0.0),
        "equivalent_gyro_bias_how": resolved.explanation,
        "gyro_arw_deg_sqrt_h": units.rad_sqrt_s_to_deg_sqrt_h(figs.gyro_arw_rad_sqrt_s),
        "gyro_arw_rad_sqrt_s": figs.gyro_arw_rad_sqrt_s,
        "heading_error_deg": units.rad_to_deg(resolved.heading_error_rad),
        "heading_error_rad": resolved.heading_error_rad,
        "heading_error_source": resolved.heading_route,
        "level_error_deg": units.rad_to_deg(figs.level_error_rad),
        "level_error_rad": figs.level_error_rad,
        "odo_scale_noise_per_sqrt_s": figs.odo_scale_noise_per_sqrt_s,
        "odo_scale_error": figs.odo_scale_error,
        "fix_spacing_m": figs.fix_spacing_m,
        "speed_m_s": figs.speed_m_s,
        "interval_s": float(case.interval_s),
        "fix_sigma_mm": units.m_to_mm(figs.fix_sigma_m),
        "fix_sigma_m": figs.fix_sigma_m,
        "initial_position_sigma_mm": units.m_to_mm(case.initial.position_m),
        "latitude_deg": units.rad_to_deg(figs.latitude_rad),
        "latitude_rad": figs.latitude_rad,
        "target_mm": target_mm,
        "target_m": target,
    }
    if monte_carlo_runs:
        mc = B.monte_carlo(case, monte_carlo_runs, seed=seed, progress=progress)
        out["monte_carlo"] = {
            "runs": mc.runs, "seed": seed, "dt_s": float(mc.times_s[1] - mc.times_s[0]), "block_runs": mc.block_runs,
            "relative_sampling_error": mc.relative_sampling_error(),
            **{d: {"mid_rms_mm": units.m_to_mm(mc.rms_m[d][mc.mid_index]),
                   "mid_sigma_mm": units.m_to_mm(mc.sigma_m[d][mc.mid_index]),
                   "worst_rms_mm": units.m_to_mm(mc.rms_m[d][mc.worst_index[d]]),
                   "worst_sigma_mm": units.m_to_mm(mc.sigma_m[d][mc.worst_index[d]]),
                   "worst_at_m": float(mc.times_s[mc.worst_index[d]]) * figs.speed_m_s}
               for d in B.DIRECTIONS},
        }
    return out


def _limits(case, resolved, figs, target):
    """The sizing limits (Jiang 2017 Fig. 6b/d/f and the fix spacing), in datasheet units."""
    from trolley import budget as B
    from trolley import units

    notes: dict[str, str] = {}
    unbounded: list[str] = []

    def one(size, parameter, direction, convert, key):
        try:
            x = size()
        except B.TargetNotReachableError as exc:
            notes[key] = str(exc)
            return None
        if math.isinf(x):
            notes[key] = (f"no {B.PARAMETER_LABELS[parameter]} up to the search cap brings the {direction} "
                          f"worst point above the target")
            unbounded.append(key)
            return None
        if parameter == "fix_spacing_m" and x < RANGES["fix_spacing_m"][0]:
            notes[key] = (f"the largest {direction} fix spacing, {x:.3g} m, is below the "
                          f"{RANGES['fix_spacing_m'][0]:g} m this budget models (--fix-spacing-m)")
        return convert(x)

    def held(parameter, direction, convert, key):
        return one(lambda: B.max_allowed(case, parameter, direction, target), parameter, direction, convert, key)

    bias = {d: held("gyro_bias_rad_s", d, units.rad_s_to_deg_h, f"max_gyro_bias_deg_h.{d}")
            for d in ("lateral", "vertical")}
    arw = {d: held("gyro_arw_rad_sqrt_s", d, units.rad_sqrt_s_to_deg_sqrt_h, f"max_gyro_arw_deg_sqrt_h.{d}")
           for d in ("lateral", "vertical")}
    odo = held("odo_scale_noise_per_sqrt_s", "longitudinal", float, "max_odo_scale_noise_per_sqrt_s")
    spacing = {d: held("fix_spacing_m", d, float, f"max_fix_spacing_m.{d}") for d in B.DIRECTIONS}
    finite = [x for x in spacing.values() if x is not None]
    limits = {
        "max_gyro_bias_deg_h": bias,
        "max_gyro_arw_deg_sqrt_h": arw,
        "max_odo_scale_noise_per_sqrt_s": odo,
        "max_fix_spacing_m": min(finite) if finite else None,
        "max_fix_spacing_m_by_direction": spacing,
    }
    if resolved.bias_route == "derived":
        # sized on the bias instability itself, the case re-resolved at each trial value: a
        # gyrocompassing heading error (and with it the Earth-rate term) follows it
        limits["max_gyro_bias_instability_deg_h"] = {
            d: one(lambda d=d: B.max_gyro_bias_instability(figs, d, target), "gyro_bias_instability_rad_s", d,
                   units.rad_s_to_deg_h, f"max_gyro_bias_instability_deg_h.{d}")
            for d in ("lateral", "vertical")}
    return limits, notes, unbounded


def _print_table(rep: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    inp = rep["inputs"]
    con.print(f"[bold]Accuracy budget[/bold]: {inp['fix_spacing_m']:g} m between fixes at {inp['speed_m_s']:g} m/s "
              f"(T = {inp['interval_s']:g} s), fix sigma {inp['fix_sigma_mm']:g} mm, IMU {inp['imu']}, "
              f"target {inp['target_mm']:g} mm (1 sigma)", highlight=False)
    bi = inp["gyro_bias_instability_deg_h"]
    con.print(f"equivalent gyro bias {inp['equivalent_gyro_bias_deg_h']:.4g} deg/h "
              + (f"(bias instability {bi:.4g} + Earth-rate term {inp['earth_rate_heading_term_deg_h']:.4g})"
                 if bi is not None else "(given)")
              + f", ARW {inp['gyro_arw_deg_sqrt_h']:.4g} deg/sqrt(h), heading error {inp['heading_error_deg']:.4g} deg "
              f"({inp['heading_error_source']}), level error {inp['level_error_deg']:.4g} deg, "
              f"odometer noise {inp['odo_scale_noise_per_sqrt_s']:.3g}/sqrt(s), scale error {inp['odo_scale_error']:.3g}",
              highlight=False)
    con.print(f"[dim]{inp['equivalent_gyro_bias_how']}[/dim]", highlight=False)
    t = Table(title="1-sigma position error along the interval (mm)")
    for col in ("direction", "mid-interval", "worst", "worst at (m)", "result", "margin"):
        t.add_column(col, justify="right" if col != "direction" else "left")
    for d in ("vertical", "lateral", "longitudinal"):
        r = rep[d]
        verdict = "[green]PASS[/green]" if r["pass"] else "[red]FAIL[/red]"
        t.add_row(d, f"{r['mid_mm']:.3f}", f"{r['max_mm']:.3f}", f"{r['worst_at_m']:.1f}", verdict,
                  f"{r['margin_mm']:+.3f}")
    con.print(t)
    rows = (
        ("initial position (first fix)", "initial_position", "initial_position", "initial_position"),
        ("level / heading / odo scale error", "level_error", "heading_error", "odo_scale_error"),
        ("equivalent gyro bias", "gyro_bias", "gyro_bias", None),
        ("ARW / odo scale noise", "angle_random_walk", "angle_random_walk", "odo_scale_noise"),
        ("fix noise (second fix)", "fix_noise", "fix_noise", "fix_noise"),
    )
    # both points: with a good IMU the worst point is at a fix, where the gyro terms vanish
    for where, src_key, total_key in (("MID-INTERVAL", "sources_mid_mm", "mid_mm"),
                                      ("the WORST POINT", "sources_max_mm", "max_mm")):
        s = Table(title=f"Contributions at {where} (mm; they add in quadrature)")
        s.add_column("source")
        for d in ("vertical", "lateral", "longitudinal"):
            s.add_column(d, justify="right")
        src = {d: rep[d][src_key] for d in ("vertical", "lateral", "longitudinal")}
        if total_key == "max_mm":
            s.add_row("[dim]at (m from the first fix)[/dim]",
                      *(f"[dim]{rep[d]['worst_at_m']:.1f}[/dim]" for d in ("vertical", "lateral", "longitudinal")))
        for label, *keys in rows:
            s.add_row(label, *("-" if k is None else f"{src[d][k]:.3f}"
                               for d, k in zip(("vertical", "lateral", "longitudinal"), keys)))
        s.add_row("total", *(f"{rep[d][total_key]:.3f}" for d in ("vertical", "lateral", "longitudinal")))
        con.print(s)
    lim = rep["limits"]
    L = Table(title=f"Sizing limits for the {inp['target_mm']:g} mm target (other inputs held)")
    L.add_column("quantity")
    L.add_column("lateral", justify="right")
    L.add_column("vertical", justify="right")
    L.add_column("longitudinal", justify="right")
    unbounded = set(rep["limits_unbounded"])

    def fmt(key: str, f: str = "{:.4g}") -> str:
        # keys as in limit_notes: "group.direction"; the spacing per direction has its own group
        group, _, direction = key.partition(".")
        if group == "max_fix_spacing_m":
            group = "max_fix_spacing_m_by_direction"
        x = lim[group][direction] if direction else lim[group]
        if x is None:
            return "any to the cap" if key in unbounded else "none meets"
        return f.format(x)

    L.add_row("equivalent gyro bias (deg/h)", fmt("max_gyro_bias_deg_h.lateral"),
              fmt("max_gyro_bias_deg_h.vertical"), "-")
    if "max_gyro_bias_instability_deg_h" in lim:
        follows = inp["heading_error_source"] == "gyrocompassing"
        L.add_row("gyro bias instability (deg/h)" + (" *" if follows else ""),
                  fmt("max_gyro_bias_instability_deg_h.lateral"), fmt("max_gyro_bias_instability_deg_h.vertical"), "-")
    L.add_row("angle random walk (deg/sqrt(h))", fmt("max_gyro_arw_deg_sqrt_h.lateral"),
              fmt("max_gyro_arw_deg_sqrt_h.vertical"), "-")
    L.add_row("odometer scale noise (1/sqrt(s))", "-", "-", fmt("max_odo_scale_noise_per_sqrt_s", "{:.3g}"))
    L.add_row("fix spacing (m)", *(fmt(f"max_fix_spacing_m.{d}", "{:.1f}") for d in ("lateral", "vertical", "longitudinal")))
    con.print(L)
    if "max_gyro_bias_instability_deg_h" in lim and inp["heading_error_source"] == "gyrocompassing":
        con.print("[dim]* with the gyrocompassing heading error and the equivalent bias following the bias "
                  "instability (equivalent bias = 2 x bias instability)[/dim]", highlight=False)
    for k, msg in rep["limit_notes"].items():
        con.print(f"[dim]{escape(str(k))}: {escape(str(msg))}[/dim]", highlight=False)
    if "monte_carlo" in rep:
        mc = rep["monte_carlo"]
        m = Table(title=f"Monte Carlo, {mc['runs']} intervals (RMS relative sampling error "
                        f"{100 * mc['relative_sampling_error']:.2f} %)")
        for col in ("direction", "mid RMS", "mid sigma", "worst RMS", "worst sigma"):
            m.add_column(col, justify="right" if col != "direction" else "left")
        for d in ("vertical", "lateral", "longitudinal"):
            r = mc[d]
            m.add_row(d, f"{r['mid_rms_mm']:.3f}", f"{r['mid_sigma_mm']:.3f}", f"{r['worst_rms_mm']:.3f}",
                      f"{r['worst_sigma_mm']:.3f}")
        con.print(m)
    con.print("[bold green]PASS[/bold green]" if rep["pass"] else "[bold red]FAIL[/bold red]: see the table above")


def write_plots(folder: Path, imu: str, figs, rep: dict) -> list[Path]:
    """PNG figures and CSV data: sigma along the interval, and max bias versus ARW curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from trolley import budget as B
    from trolley import error_models as em
    from trolley import units
    from trolley.sensors import IMU_PRESETS

    folder.mkdir(parents=True, exist_ok=True)
    resolved = B.resolve_case(figs)
    if resolved.heading_route == "gyrocompassing" and resolved.heading_error_rad > units.deg_to_rad(MAX_HEADING_ERROR_DEG):
        raise BudgetInputError(
            f"this IMU gyrocompasses to a heading error of {units.rad_to_deg(resolved.heading_error_rad):.3g} deg at "
            f"--latitude-deg {units.rad_to_deg(figs.latitude_rad):g}, beyond the {MAX_HEADING_ERROR_DEG:g} deg the "
            "small-angle error model takes: it cannot find north by itself; give --heading-error-deg")
    case = resolved.case
    T = float(case.interval_s)
    t = np.linspace(0.0, T, 241)
    sig = B.sigma_along(case, t)
    target = rep["inputs"]["target_mm"]
    written = []

    def csv_text(header, cols):
        m = np.column_stack(cols)
        return ",".join(header) + "\n" + "\n".join(",".join(repr(float(x)) for x in row) for row in m) + "\n"

    dist = t * figs.speed_m_s
    text = csv_text(["distance_m", "time_s", "vertical_mm", "lateral_mm", "longitudinal_mm"],
                    [dist, t] + [units.m_to_mm(sig[d]) for d in ("vertical", "lateral", "longitudinal")])
    p = folder / "budget_sigma.csv"
    write_text_atomic(p, text)
    written.append(p)

    fig, ax = plt.subplots(figsize=(7, 4))
    for d in ("vertical", "lateral", "longitudinal"):
        ax.plot(dist, units.m_to_mm(sig[d]), label=d)
    ax.axhline(target, color="k", ls="--", lw=1, label=f"target {target:g} mm")
    ax.set_xlabel("distance from the first fix (m)")
    ax.set_ylabel("smoothed position 1-sigma (mm)")
    ax.set_title(f"Accuracy along the interval ({imu}, {figs.fix_spacing_m:g} m between fixes)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    p = folder / "budget_sigma.png"
    write_with(p, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    plt.close(fig)
    written.append(p)

    # requirement curves (Jiang 2017 Fig. 6b/d): max equivalent bias versus ARW
    arw_now = units.rad_sqrt_s_to_deg_sqrt_h(figs.gyro_arw_rad_sqrt_s)
    lim_arw = [x for x in rep["limits"]["max_gyro_arw_deg_sqrt_h"].values() if x is not None]
    top = max([arw_now * 1.5, 0.01] + [1.05 * x for x in lim_arw])
    arw = np.linspace(0.0, top, 200)
    arw_si = units.deg_sqrt_h_to_rad_sqrt_s(arw)
    grid_case = B.BudgetCase(case.initial, em.ChannelNoise(arw_si, case.noise.odo_scale_noise_per_sqrt_s),
                             case.fix_sigma_m, case.speed_m_s, case.fix_spacing_m)
    target_m = units.mm_to_m(target)
    curves = {d: units.rad_s_to_deg_h(B.max_allowed_grid(grid_case, "gyro_bias_rad_s", d, target_m))
              for d in ("lateral", "vertical")}
    text = csv_text(["gyro_arw_deg_sqrt_h", "max_gyro_bias_lateral_deg_h", "max_gyro_bias_vertical_deg_h"],
                    [arw, curves["lateral"], curves["vertical"]])
    p = folder / "budget_requirements.csv"
    write_text_atomic(p, text)
    written.append(p)

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for d, style in (("lateral", "-"), ("vertical", "--")):
        y = np.where(np.isfinite(curves[d]), curves[d], np.nan)
        ax.plot(arw, y, style, label=f"{d}: largest equivalent bias")
    ax.plot([arw_now], [rep["inputs"]["equivalent_gyro_bias_deg_h"]], "r*", ms=12, label=f"this IMU ({imu})")
    for name, pr in IMU_PRESETS.items():
        # the other presets, through the same derived route (gyrocompassing heading at this latitude)
        if name == imu or not pr.gyrocompassing:
            continue
        x = units.rad_sqrt_s_to_deg_sqrt_h(pr.gyro_arw_rad_sqrt_s)
        other = B.resolve_case(B.SensorFigures(pr.gyro_arw_rad_sqrt_s,
                                               gyro_bias_instability_rad_s=pr.gyro_bias_instability_rad_s,
                                               latitude_rad=figs.latitude_rad))
        y = units.rad_s_to_deg_h(other.equivalent_gyro_bias_rad_s)
        if x <= top:
            ax.plot([x], [y], "ko", ms=5)
            ax.annotate(f"{name} (gyrocompassing)", (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    ax.set_xlabel("angle random walk (deg/sqrt(h))")
    ax.set_ylabel("equivalent gyro bias (deg/h)")
    ax.set_title(f"Requirement for {target:g} mm at the worst point (below the line meets it)")
    finite = np.concatenate([c[np.isfinite(c)] for c in curves.values()] + [[rep["inputs"]["equivalent_gyro_bias_deg_h"]]])
    ax.set_ylim(0, 1.2 * float(np.max(finite)) if finite.size else 1.0)
    ax.set_xlim(0, top)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = folder / "budget_requirements.png"
    write_with(p, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    plt.close(fig)
    written.append(p)
    return written


def budget_command(
    imu: Annotated[Optional[BudgetImu], typer.Option("--imu", case_sensitive=False,
                                                     help="IMU preset, or custom figures (default rlg; custom "
                                                          "when a bias and the ARW are given)")] = None,
    gyro_bias_deg_h: Annotated[Optional[float], typer.Option(
        "--gyro-bias-deg-h", help="equivalent gyro bias, used as given (Jiang 2017 Eq. 15-16)")] = None,
    gyro_bias_instability_deg_h: Annotated[Optional[float], typer.Option(
        "--gyro-bias-instability-deg-h", help="datasheet bias instability; the equivalent bias is derived "
                                              "with the Earth-rate term at --latitude-deg")] = None,
    gyro_arw_deg_sqrt_h: Annotated[Optional[float], typer.Option(
        "--gyro-arw-deg-sqrt-h", help="gyro angle random walk")] = None,
    heading_error_deg: Annotated[Optional[float], typer.Option(
        "--heading-error-deg", help="initial heading error (default: gyrocompassing with the bias)")] = None,
    level_error_deg: Annotated[float, typer.Option("--level-error-deg", help="initial equivalent level error")] = 0.005,
    odo_scale_noise: Annotated[Optional[float], typer.Option(
        "--odo-scale-noise", help="odometer scale-factor noise, 1/sqrt(s) (default: the odometer of "
                                  "trolley.sensors.OdometerFigures, Jiang 2017 Eq. 46)")] = None,
    odo_scale_error: Annotated[Optional[float], typer.Option(
        "--odo-scale-error", help="odometer scale-factor error left after calibration, constant over the "
                                  "interval (default: trolley.budget.BUDGET_ODO_SCALE_ERROR, 0; docs/budget.md)")] = None,
    fix_spacing_m: Annotated[float, typer.Option("--fix-spacing-m", help="distance between fixes")] = 60.0,
    speed_m_s: Annotated[float, typer.Option("--speed-m-s", help="trolley speed")] = 1.0,
    fix_sigma_mm: Annotated[float, typer.Option("--fix-sigma-mm", help="1-sigma of a total-station fix")] = 0.6,
    latitude_deg: Annotated[float, typer.Option("--latitude-deg", help="site latitude")] = 30.0,
    target_mm: Annotated[float, typer.Option("--target-mm", help="1-sigma target at the worst point")] = 0.67,
    monte_carlo: Annotated[int, typer.Option("--monte-carlo", help="also simulate N intervals (0: no)")] = 0,
    seed: Annotated[int, typer.Option("--seed", help="random seed of the Monte Carlo")] = 0,
    plot: Annotated[Optional[Path], typer.Option("--plots", help="write PNG figures and CSV data to this folder")] = None,
    json_output: Annotated[bool, typer.Option("--json", help="print one JSON object on stdout, nothing else")] = False,
    plot_old: Annotated[Optional[Path], typer.Option("--plot", hidden=True, help=old_name("--plots"))] = None,
) -> None:
    """Accuracy budget of one fix interval and IMU/odometer sizing (Jiang 2017 Sec. 5).

    Exit code 0: every direction meets the target; 1: at least one does not; 2: bad input.
    See docs/budget.md.
    """
    from trolley.budget import TargetNotReachableError

    plot = renamed(plot, plot_old, "--plots", "--plot")
    try:
        # `error: --option: what is wrong`, as survey.limits.check_integer says it for every other option
        if monte_carlo < 0:
            raise BudgetInputError(f"--monte-carlo: must be >= 0, got {monte_carlo}")
        if monte_carlo == 1:
            raise BudgetInputError("--monte-carlo: must be 0 (none) or >= 2, got 1 (one run has no spread)")
        if monte_carlo > MAX_MONTE_CARLO_RUNS:
            raise BudgetInputError(f"--monte-carlo: must be <= {MAX_MONTE_CARLO_RUNS}, got {monte_carlo} (their RMS "
                                   f"then has a {100 / math.sqrt(2 * MAX_MONTE_CARLO_RUNS):.2f} % sampling error)")
        from survey.limits import check_finite, check_seed

        check_seed(seed)
        check_finite(target_mm, "--target-mm", positive=True, maximum=RANGES["fix_sigma_mm"][1],
                     why="the range of the fix sigma: a looser target sizes nothing")
        imu_name, figs = sensor_figures(imu, gyro_bias_deg_h, gyro_bias_instability_deg_h, gyro_arw_deg_sqrt_h,
                                        heading_error_deg, level_error_deg, odo_scale_noise, odo_scale_error,
                                        fix_spacing_m, speed_m_s, fix_sigma_mm, latitude_deg)
        if monte_carlo:
            from survey.commands.progress import progress_bar

            with progress_bar("Monte Carlo") as report:
                rep = compute_report(imu_name, figs, target_mm, monte_carlo, seed, report)
        else:
            rep = compute_report(imu_name, figs, target_mm, monte_carlo, seed)
    except (BudgetInputError, TargetNotReachableError, ValueError) as exc:
        _fail(str(exc))
        return
    except MemoryError:
        _fail(f"not enough memory for this budget (--monte-carlo {monte_carlo} over {fix_spacing_m:g} m at "
              f"{speed_m_s:g} m/s): use fewer --monte-carlo runs or a shorter --fix-spacing-m")
        return
    if plot is not None:
        if plot.exists() and not plot.is_dir():
            _fail(f"--plots {plot}: exists and is not a folder")
        try:
            files = write_plots(plot, imu_name, figs, rep)
        except OSError as exc:
            _fail(f"--plots {plot}: cannot write ({exc.strerror or exc})")
            return
        rep["plots"] = [str(f) for f in files]
    if json_output:
        jsonout.echo(rep, indent=2)
    else:
        _print_table(rep)
        if plot is not None:
            typer.echo("wrote " + ", ".join(rep["plots"]), err=True)
    raise typer.Exit(code=0 if rep["pass"] else 1)


def register(app: typer.Typer) -> None:
    """Add ``trolley budget`` to the app."""
    app.command("budget")(budget_command)
