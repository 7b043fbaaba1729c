"""PNG plots of the survey (matplotlib, Agg): deviations, gauge, cant, twist, chords and bands
against chainage; the same panels are the strip charts of the PDF report (survey/reportpdf.py).

Chainage axes are labelled in km+m (1+234.5); each y axis names the quantity, its unit and sign
convention (the Track sheet's column header); each quantity with a limit has its own panel, with
the allowed band shaded green and beyond it red; defects are red vertical bands; the
deviations carry their 1-sigma band (sigma lateral / vertical of the Track sheet); CPIII fixes
are marked on the chainage axis (accepted: black triangles, rejected: red crosses) and the
trolley's stops as thin grey lines; the band-pass edge zones, where the deviation has values but
the band has none because the filter's start-up transient would remain (within one longest
wavelength of the band from the end of the record, trolley/bands.py "NaN gaps"), are hatched grey; the long-chord checks are drawn
as their magnitude (the value is the largest difference along the chord with its sign, which
flips from one station to the next: drawn signed it reads as a comb).

The magnitude of a check with more than two points spacings along the chord (30 m / 5 m) rises
and falls with a period of one spacing p, and that is the check itself, not the drawing: the
largest difference of points p apart takes a steep stretch of the deviation whole when the
chord's points straddle it and split over two pairs when they do not, so as the chord slides
by 0.625 m the value cycles every p (a single 1 mm ramp over 2 m reads 0.83, 0.52, 0.46, 0.77,
0.83 mm ... every 5 m; a pure 20 m sine of 0.5 mm between 0.50 and 0.83 mm). Such a panel draws
the per-station values thin and, as its line, their maximum over one spacing
(:func:`chord_envelope`): the check with the chord's points at their worst place.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from survey.atomicwrite import write_with
from trolley.bands import BANDS
from trolley.trackgeometry import ABSOLUTE_COLUMNS, band_source

from survey.track_table import SurveyReport, fix_chainages, limit_in_display

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
#: columns drawn with a 1-sigma band: column -> its sigma column
SIGMA_OF = {"lateral_dev_m": "sigma_lateral_m", "vertical_dev_m": "sigma_vertical_m"}


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


def is_chord(key: str) -> bool:
    """A long-chord check column (drawn as its magnitude)."""
    return key.startswith("chord")


def chord_spacing_m(rep: SurveyReport, key: str) -> float | None:
    """The point spacing p of the long-chord check ``key`` if its magnitude cycles with p (more
    than two spacings along the chord), else None (B = 2p: the value is +-one versine)."""
    from trolley.trackgeometry import long_chord_name

    for chord, spacing in rep.geometry.config.long_chords_m:
        if key in (long_chord_name(chord, spacing, "lat"), long_chord_name(chord, spacing, "vert")):
            return float(spacing) if round(chord / spacing) > 2 else None
    return None


def chord_envelope(magnitude: np.ndarray, spacing_m: float, step_m: float) -> np.ndarray:
    """The largest magnitude within half a spacing either side of each station (a centred running
    maximum over one spacing p, scipy.ndimage.maximum_filter1d); NaN where the value is NaN."""
    from scipy.ndimage import maximum_filter1d

    v = np.asarray(magnitude, dtype=float)
    half = int(round(0.5 * spacing_m / step_m))
    out = maximum_filter1d(np.where(np.isnan(v), -np.inf, v), size=2 * half + 1, mode="nearest")
    out[np.isnan(v)] = np.nan
    return out


def edge_zones(chainage_m: np.ndarray, values: np.ndarray, source: np.ndarray | None,
               key: str) -> list[tuple[float, float]]:
    """Chainage intervals of a band-passed column left empty for the filter's edge transient:
    where its ``source`` (the deviation it is filtered from) has values and it has none
    ([] for other columns or without a source)."""
    band = key.split("_")[1] if key.startswith(("align_D", "level_D")) else None
    if band not in BANDS or source is None:
        return []
    empty = (np.isfinite(source) & ~np.isfinite(values)).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], empty, [0]))))
    return [(float(chainage_m[a]), float(chainage_m[b])) for a, b in zip(edges[::2], edges[1::2] - 1)]


def draw_panel(ax, rep: SurveyReport, keys: list[str], marks: tuple[np.ndarray, np.ndarray, np.ndarray],
               xlim: tuple[float, float] | None = None) -> bool:
    """Draw one panel (the columns ``keys`` on one y axis) into ``ax``.

    Parameters
    ----------
    marks : (accepted fix chainages, rejected fix chainages, stop chainages).
    xlim : chainage range shown (None: the whole survey); the y range follows the values in it.

    Returns
    -------
    True if anything was drawn (False: no values in the range).
    """
    s = rep.geometry.chainage_m
    by_key = {c.key: c for c in rep.columns}
    sel = np.ones(s.size, bool) if xlim is None else (s >= xlim[0]) & (s <= xlim[1])
    colours = ["tab:blue", "tab:orange", "tab:green"]
    vals = []
    drawn_unfixed = False
    for n, k in enumerate(keys):
        col = by_key[k]
        v = col.display(rep.geometry.columns[k])
        label = col.header
        if is_chord(k):
            v = np.abs(v)
            label = "|" + col.header.replace(" [mm]", "| [mm]", 1)
        if not np.isfinite(v[sel]).any():
            continue
        p = chord_spacing_m(rep, k) if is_chord(k) else None
        if p is not None:   # the per-station values thin; the line is their maximum over one spacing
            ax.plot(s[sel], v[sel], lw=0.4, color=colours[n % 3], alpha=0.35, label=f"{label} per station")
            v = chord_envelope(v, p, rep.geometry.step_m)
            label = f"{label}, max over {p:g} m"
        scale = sel
        if k in ABSOLUTE_COLUMNS and rep.absolute_checked is not None and (sel & rep.absolute_checked).any():
            # the y range follows the checked stations: hundreds of mm of drift beyond the fixes
            # flattened the checked part and its 10 mm band to a line (it runs off the panel)
            scale = sel & rep.absolute_checked
        vals.append(v[scale][np.isfinite(v[scale])])
        ax.plot(s[sel], v[sel], lw=0.9, color=colours[n % 3], label=label)
        if k in SIGMA_OF:
            sig = by_key[SIGMA_OF[k]].display(rep.geometry.columns[SIGMA_OF[k]])
            ax.fill_between(s[sel], (v - sig)[sel], (v + sig)[sel], color=colours[n % 3], alpha=0.25, lw=0,
                            label="±1σ")
        if k in ABSOLUTE_COLUMNS and not drawn_unfixed:
            # the stations outside the outermost fixes (each standing for half a step either side):
            # dead reckoning from one fix, not checked
            h = 0.5 * rep.geometry.step_m
            for j, (a, b) in enumerate(rep.unchecked_runs()):
                # over the tolerance zones and the sigma band, under the line: washed out, not hidden
                ax.axvspan(s[a] - h, s[b] + h, facecolor="0.92", alpha=0.75, lw=0, zorder=1.5,
                           label="beyond the fixes: dead reckoning, not checked" if j == 0 else None)
            drawn_unfixed = True
        zones = edge_zones(s, rep.geometry.columns[k], rep.geometry.columns.get(band_source(k)), k)
        for j, (a, b) in enumerate(zones):
            ax.axvspan(a, b, facecolor="none", edgecolor="0.5", hatch="///", lw=0, zorder=0,
                       label="band-pass edge zone (no value)" if j == 0 else None)
    if not vals:
        return False
    allv = np.concatenate(vals)
    peak = float(np.max(np.abs(allv))) if allv.size else 1.0
    lim = _panel_limit(rep, keys)
    chord = any(is_chord(k) for k in keys)
    if lim is not None:
        lo, hi, name = lim
        edges = [abs(x) for x in (lo, hi) if math.isfinite(x)]
        top = max([peak] + edges) * 1.25 or 1.0
        bottom = -0.05 * top if chord else -top
        ax.set_ylim(bottom, top)
        ax.axhspan(max(lo, bottom) if math.isfinite(lo) else bottom, hi if math.isfinite(hi) else top,
                   color="tab:green", alpha=0.12, lw=0, label=f"tolerance {name} ({rep.tolerances.name})")
        if math.isfinite(hi):
            ax.axhspan(hi, max(hi, top), color="tab:red", alpha=0.10, lw=0)
        if math.isfinite(lo) and not chord:
            ax.axhspan(min(lo, bottom), lo, color="tab:red", alpha=0.10, lw=0)
    for d in rep.defects:
        if d.column in keys:
            ax.axvspan(d.start_chainage_m, d.end_chainage_m + rep.geometry.step_m, color="tab:red", alpha=0.3, lw=0)
    acc, rej, stops = marks
    in_x = (lambda x: x) if xlim is None else (lambda x: x[(x >= xlim[0]) & (x <= xlim[1])])
    for p in in_x(stops):
        ax.axvline(p, color="0.6", lw=0.5, zorder=0)
    tr = ax.get_xaxis_transform()
    if in_x(acc).size:
        ax.plot(in_x(acc), np.zeros(in_x(acc).size), "^", color="black", ms=5, transform=tr, clip_on=False,
                label="CPIII fix")
    if in_x(rej).size:
        ax.plot(in_x(rej), np.zeros(in_x(rej).size), "x", color="tab:red", ms=6, mew=1.5, transform=tr,
                clip_on=False, label="rejected / undone fix")
    head = by_key[keys[0]].header
    head = ("|" + head.replace(" [mm]", "| [mm]", 1)) if chord else head
    ax.set_ylabel(head.replace("] ", "]\n", 1), fontsize=8)   # quantity [unit] / sign convention
    ax.grid(True, lw=0.4, alpha=0.6)
    ax.legend(loc="upper right", fontsize=7, ncol=3)
    if xlim is not None:
        ax.set_xlim(*xlim)
    return True


def panel_marks(rep: SurveyReport) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(accepted fix, rejected fix, stop) chainages for :func:`draw_panel`."""
    acc, rej = fix_chainages(rep.geometry, rep.fixes, rep.record)
    stops = np.array([p.chainage_m for p in rep.record.stops if math.isfinite(p.chainage_m)]) \
        if rep.record is not None else np.zeros(0)
    return acc, rej, stops


def km_axis(ax, rep: SurveyReport | None = None) -> None:
    """Label a chainage x axis in km+m.

    The axis runs along the internal station (the distance: no gap or fold at a station
    equation); with ``rep`` the labels are its drawing stationing (:meth:`SurveyReport.station`)
    and each station equation in the survey is a dashed vertical line with its text.
    """
    from matplotlib.ticker import FuncFormatter

    station = (lambda x: x) if rep is None else rep.station
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: km_label(station(x), 1)))
    ax.set_xlabel("chainage [km+m]" + (" (drawing stationing)" if rep is not None and rep.equations() else ""))
    for s, text in ([] if rep is None else rep.equations()):
        shown = [a for a in ax.get_figure().axes if a.get_xlim()[0] <= s <= a.get_xlim()[1]]
        for a in shown:
            a.axvline(s, color="black", ls="--", lw=0.8)
        if shown:   # "1+300.000 back = 2+300.000 ahead" at the foot of the first panel (the legend is at the top)
            label = " " + text.split(": ", 1)[1].split(" (")[0]
            shown[0].text(s, 0.03, label, transform=shown[0].get_xaxis_transform(),
                          fontsize=7, va="bottom", ha="left", zorder=6,
                          bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1})


def write_plots(folder: Path, rep: SurveyReport) -> list[Path]:
    """Write the PNG plots into ``folder`` (created); returns the files written.

    Panels whose parameters have no values (e.g. chords and bands without a design) are left
    out, and a figure with no panel left is not written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    marks = panel_marks(rep)
    written = []
    for stem, title, panels in PLOTS:
        panels = [[k for k in p if k in rep.geometry.columns and rep.stats[k].count > 0] for p in panels]
        panels = [p for p in panels if p]
        if not panels:
            continue
        fig, axes = plt.subplots(len(panels), 1, figsize=(11, 1.2 + 2.6 * len(panels)), dpi=110,
                                 sharex=True, squeeze=False)
        for ax, keys in zip(axes[:, 0], panels):
            draw_panel(ax, rep, keys, marks)
        km_axis(axes[-1, 0], rep)
        names = " / ".join(x for x in (rep.info.project, rep.info.session) if x) or rep.track_csv.name
        axes[0, 0].set_title(f"{title} - {names}")
        fig.tight_layout()
        out = folder / f"{stem}.png"
        try:
            write_with(out, lambda tmp: fig.savefig(tmp, format="png"))
        finally:
            plt.close(fig)
        written.append(out)
    return written
