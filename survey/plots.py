"""PNG plots of the survey (matplotlib, Agg): deviations, gauge, cant, twist against chainage.

Chainage axes are labelled in km+m (1+234.5); each quantity with a limit has its own panel, with
the allowed band shaded green and beyond it red; defects are marked as red vertical bands; units
are on every axis and in the legends.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from survey.atomicwrite import write_with
from survey.track_table import SurveyReport, limit_in_display

#: file stem, title, panels (each a list of geometry columns sharing one y axis and unit)
PLOTS = [
    ("deviations", "Deviation from design", [["lateral_dev_m"], ["vertical_dev_m"]]),
    ("gauge", "Gauge", [["gauge_dev_m"], ["gauge_rate_m_per_m"]]),
    ("cant", "Cant", [["cant_m", "design_cant_m"], ["cant_dev_m"]]),
    ("twist", "Twist", [["twist_m"], ["twist_dev_m"]]),
    ("chords_lateral", "Alignment on chords (lateral)",
     [["versine_h_dev_m"], ["chord30_5_lat_m"], ["chord300_150_lat_m"]]),
    ("chords_vertical", "Longitudinal level on chords (vertical)",
     [["versine_v_dev_m"], ["chord30_5_vert_m"], ["chord300_150_vert_m"]]),
    ("alignment_bands", "Alignment (lateral), EN 13848 bands", [["align_D1_m"], ["align_D2_m"], ["align_D3_m"]]),
    ("level_bands", "Longitudinal level, EN 13848 bands", [["level_D1_m"], ["level_D2_m"], ["level_D3_m"]]),
]


def km_label(chainage_m: float, decimals: int = 1) -> str:
    """Chainage as km+m text, e.g. 1234.5 -> '1+234.5', -20 -> '-0+020.0'."""
    sign = "-" if chainage_m < 0 else ""
    a = round(abs(chainage_m), decimals)
    km = int(a // 1000)
    m = a - 1000 * km
    width = 4 + decimals if decimals else 3
    return f"{sign}{km}+{m:0{width}.{decimals}f}"


def _panel_limit(rep: SurveyReport, keys: list[str]) -> tuple[float, float, str] | None:
    """(lower, upper, label) in display units of the limit that applies to a panel, if any."""
    limits = {lim.column: lim for lim in rep.tolerances.limits}
    for k in keys:
        if k in limits:
            lo, hi, _ = limit_in_display(limits[k])
            return lo, hi, limits[k].parameter
    if keys == ["gauge_dev_m"] and "gauge_m" in limits:
        # an absolute gauge limit shown on the gauge deviation
        lo, hi, _ = limit_in_display(limits["gauge_m"])
        nominal = rep.geometry.config.nominal_gauge_m * 1e3
        return lo - nominal, hi - nominal, "gauge"
    return None


def write_plots(folder: Path, rep: SurveyReport) -> list[Path]:
    """Write the PNG plots into ``folder`` (created); returns the files written.

    Panels whose parameters have no values (e.g. chords and bands without a design) are left
    out, and a figure with no panel left is not written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    s = rep.geometry.chainage_m
    by_key = {c.key: c for c in rep.columns}
    written = []
    for stem, title, panels in PLOTS:
        panels = [[k for k in p if k in rep.geometry.columns and rep.stats[k].count > 0] for p in panels]
        panels = [p for p in panels if p]
        if not panels:
            continue
        fig, axes = plt.subplots(len(panels), 1, figsize=(11, 1.2 + 2.6 * len(panels)), dpi=110,
                                 sharex=True, squeeze=False)
        for ax, keys in zip(axes[:, 0], panels):
            unit = by_key[keys[0]].unit
            vals = []
            for k in keys:
                v = by_key[k].display(rep.geometry.columns[k])
                vals.append(v[np.isfinite(v)])
                ax.plot(s, v, lw=0.9, label=by_key[k].header)
            vals = np.concatenate(vals)
            peak = float(np.max(np.abs(vals))) if vals.size else 1.0
            lim = _panel_limit(rep, keys)
            if lim is not None:
                lo, hi, name = lim
                edges = [abs(x) for x in (lo, hi) if math.isfinite(x)]
                top = max([peak] + edges) * 1.25 or 1.0
                ax.set_ylim(-top, top)
                ax.axhspan(lo if math.isfinite(lo) else -top, hi if math.isfinite(hi) else top,
                           color="tab:green", alpha=0.12, lw=0,
                           label=f"tolerance {name} ({rep.tolerances.name})")
                if math.isfinite(hi):
                    ax.axhspan(hi, max(hi, top), color="tab:red", alpha=0.10, lw=0)
                if math.isfinite(lo):
                    ax.axhspan(min(lo, -top), lo, color="tab:red", alpha=0.10, lw=0)
            for d in rep.defects:
                if d.column in keys:
                    ax.axvspan(d.start_chainage_m, d.end_chainage_m + rep.geometry.step_m,
                               color="tab:red", alpha=0.3, lw=0)
            ax.set_ylabel(f"[{unit}]")
            ax.grid(True, lw=0.4, alpha=0.6)
            ax.legend(loc="upper right", fontsize=8)
        ax = axes[-1, 0]
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: km_label(x, 1)))
        ax.set_xlabel("chainage [km+m]")
        names = " / ".join(x for x in (rep.info.project, rep.info.session) if x) or str(rep.track_csv)
        axes[0, 0].set_title(f"{title} - {names}")
        fig.tight_layout()
        out = folder / f"{stem}.png"
        try:
            write_with(out, lambda tmp: fig.savefig(tmp, format="png"))
        finally:
            plt.close(fig)
        written.append(out)
    return written
