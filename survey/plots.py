"""PNG plots of the survey (matplotlib, Agg): deviations, gauge, cant, twist against chainage.

Chainage axes are labelled in km+m (1+234.5); limits of the tolerance set are shaded (the
allowed band green, beyond it red); units are on every axis.
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np

from survey.track_table import SurveyReport, limit_in_display

#: file stem, title, y label, geometry columns
PLOTS = [
    ("deviations", "Deviation from design", "deviation [mm]", ["lateral_dev_m", "vertical_dev_m"]),
    ("gauge", "Gauge deviation from nominal", "gauge - nominal [mm]", ["gauge_dev_m"]),
    ("cant", "Cant", "cant [mm]", ["cant_m", "design_cant_m", "cant_dev_m"]),
    ("twist", "Twist", "twist [mm]", ["twist_dev_m", "twist_m"]),
    ("alignment_bands", "Alignment (lateral) EN 13848 bands", "band-passed deviation [mm]",
     ["align_D1_m", "align_D2_m", "align_D3_m"]),
    ("level_bands", "Longitudinal level EN 13848 bands", "band-passed deviation [mm]",
     ["level_D1_m", "level_D2_m", "level_D3_m"]),
]


def km_label(chainage_m: float, decimals: int = 1) -> str:
    """Chainage as km+m text, e.g. 1234.5 -> '1+234.5', -20 -> '-0+020.0'."""
    sign = "-" if chainage_m < 0 else ""
    a = round(abs(chainage_m), decimals)
    km = int(a // 1000)
    m = a - 1000 * km
    width = 4 + decimals if decimals else 3
    return f"{sign}{km}+{m:0{width}.{decimals}f}"


def write_plots(folder: Path, rep: SurveyReport) -> list[Path]:
    """Write the PNG plots into ``folder`` (created); returns the files written.

    Plots whose parameters have no values (e.g. bands without a design) are skipped.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    s = rep.geometry.chainage_m
    by_key = {c.key: c for c in rep.columns}
    limits = {lim.column: lim for lim in rep.tolerances.limits}
    written = []
    for stem, title, ylabel, keys in PLOTS:
        keys = [k for k in keys if k in rep.geometry.columns and rep.stats[k].count > 0]
        if not keys:
            continue
        fig, ax = plt.subplots(figsize=(11, 4.2), dpi=110)
        shaded = False
        for k in keys:
            col = by_key[k]
            ax.plot(s, col.display(rep.geometry.columns[k]), lw=0.9, label=col.header)
            lim = limits.get(k)
            if lim is not None and not shaded:
                lo, hi, _ = limit_in_display(lim)
                ymin, ymax = ax.get_ylim()
                span = max(abs(ymin), abs(ymax), abs(lo) if math.isfinite(lo) else 0,
                           abs(hi) if math.isfinite(hi) else 0) * 1.3
                lo_d = lo if math.isfinite(lo) else -span
                hi_d = hi if math.isfinite(hi) else span
                ax.axhspan(lo_d, hi_d, color="tab:green", alpha=0.10, lw=0,
                           label=f"tolerance {lim.parameter} ({rep.tolerances.name})")
                if math.isfinite(hi):
                    ax.axhspan(hi, max(hi, span), color="tab:red", alpha=0.08, lw=0)
                if math.isfinite(lo):
                    ax.axhspan(min(lo, -span), lo, color="tab:red", alpha=0.08, lw=0)
                shaded = True
        if shaded:
            vals = np.concatenate([by_key[k].display(rep.geometry.columns[k]) for k in keys])
            vals = vals[np.isfinite(vals)]
            lims = [limit_in_display(limits[k])[:2] for k in keys if k in limits]
            edges = [abs(v) for pair in lims for v in pair if math.isfinite(v)]
            top = max([np.max(np.abs(vals))] + edges) * 1.25 if vals.size else 1.0
            ax.set_ylim(-top, top) if any(math.isfinite(p[0]) for p in lims) else ax.set_ylim(top=top)
        for d in rep.defects:
            if d.column in keys:
                ax.axvspan(d.start_chainage_m, d.end_chainage_m + rep.geometry.step_m, color="tab:red", alpha=0.25, lw=0)
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: km_label(x, 1)))
        ax.set_xlabel("chainage [km+m]")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{title} - {rep.info.project or rep.track_csv.parent.name}")
        ax.grid(True, lw=0.4, alpha=0.6)
        ax.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        out = folder / f"{stem}.png"
        fd, tmp = tempfile.mkstemp(prefix=f".{stem}-", suffix=".png", dir=folder)
        os.close(fd)
        try:
            fig.savefig(tmp, format="png")
            os.replace(tmp, out)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        finally:
            plt.close(fig)
        written.append(out)
    return written
