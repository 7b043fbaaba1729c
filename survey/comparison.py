"""Files of ``trolley compare``: the difference table (CSV), its plot (PNG) and the JSON summary.

The science is ``trolley.repeatability``; this module reads the two track.csv files, puts the
track's own drawing chainage beside the differences, converts to mm at the edge and writes the
outputs all or nothing (docs/track_geometry.md, "Two surveys of one track").
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from survey.track_reader import TrackFile, read_track_file, resolve_track_csv
from trolley import units
from trolley.repeatability import Comparison, compare_tracks

#: the quantities judged against their sigma, and the gauge, compared without one
JUDGED = ("lateral", "vertical", "cant")


@dataclass
class ComparedTracks:
    """Two track files and their comparison.

    Attributes
    ----------
    a_path, b_path : the track.csv files read.
    a, b : the files as read (``survey.track_reader.TrackFile``).
    comparison : B - A at A's stations.
    chainage_m : A's drawing chainage at its stations (its file's ``chainage_m``), m.
    """

    a_path: Path
    b_path: Path
    a: TrackFile
    b: TrackFile
    comparison: Comparison
    chainage_m: np.ndarray

    def chainage_at(self, station_m: float) -> float:
        """A's drawing chainage at its internal station ``station_m``."""
        return float(np.interp(station_m, self.comparison.difference.station_m, self.chainage_m))


def compared_tracks(a: Path, b: Path, limit: float, max_offset_m: float) -> ComparedTracks:
    """Read two tracks (files or output folders, as ``trolley export`` takes them) and compare them.

    Raises
    ------
    survey.track_reader.ExportInputError naming the file, row and column; ValueError when the
    tracks do not run beside each other.
    """
    a_path, b_path = resolve_track_csv(a), resolve_track_csv(b)
    fa, fb = read_track_file(a_path), read_track_file(b_path)
    cmp = compare_tracks(fa.track, fb.track, limit=limit, max_offset_m=max_offset_m)
    s = fa.track.chainage_m
    chainage = s.copy() if fa.stationing is None else np.asarray(fa.stationing.station(s), dtype=float)
    return ComparedTracks(a_path, b_path, fa, fb, cmp, chainage)


def difference_frame(ct: ComparedTracks) -> pd.DataFrame:
    """The difference table: one row per station of track A, empty cells where B is not beside it."""
    d = ct.comparison.difference
    mm = units.m_to_mm
    cols = {"chainage_m": ct.chainage_m, "distance_m": d.station_m}
    for q in JUDGED:
        cols[f"{q}_diff_mm"] = mm(getattr(d, f"{q}_m"))
        cols[f"sigma_{q}_diff_mm"] = mm(getattr(d, f"sigma_{q}_m"))
        cols[f"{q}_z"] = d.z(q)
    cols["gauge_diff_mm"] = mm(d.gauge_m)
    return pd.DataFrame(cols)


def summary_dict(ct: ComparedTracks) -> dict:
    """The JSON summary (SI lengths in m with a unit suffix, differences in mm)."""
    c = ct.comparison
    mm = units.m_to_mm
    return {
        "track_a": str(ct.a_path), "track_b": str(ct.b_path),
        "limit_sigma": c.limit, "common_length_m": c.common_m,
        "stations_compared": int(c.difference.beside.sum()), "stations": int(c.difference.beside.size),
        "agree": c.agree,
        "rms_mm": {q: mm(v) for q, v in c.rms_m.items()},
        "max_abs_mm": {q: mm(v) for q, v in c.max_abs_m.items()},
        "rms_z": c.rms_z,
        "sigma_median_mm": {q: mm(v) for q, v in c.sigma_median_m.items()},
        "sigma_max_mm": {q: mm(v) for q, v in c.sigma_max_m.items()},
        "stations_beyond": c.beyond,
        "stations_zero_sigma": c.zero_sigma,
        "stretches_beyond": [
            {"quantity": s.quantity, "from_chainage_m": ct.chainage_at(s.start_m),
             "to_chainage_m": ct.chainage_at(s.end_m), "stations": s.stations,
             "max_abs_diff_mm": mm(s.max_abs_diff_m), "max_abs_z": s.max_abs_z,
             "at_chainage_m": ct.chainage_at(s.at_m)} for s in c.stretches],
        "band_rms_mm": {q: {b: mm(v) for b, v in bands.items()} for q, bands in c.band_rms_m.items()},
    }


def write_difference_plot(path: Path, ct: ComparedTracks) -> None:
    """PNG: lateral, vertical and cant differences against A's chainage with their +-limit sigma band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from survey.atomicwrite import write_with

    d = ct.comparison.difference
    k = ct.comparison.limit
    panels = [q for q in JUDGED if np.isfinite(getattr(d, f"{q}_m")).any()]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 1.2 + 2.4 * len(panels)), dpi=110, sharex=True,
                             squeeze=False)
    x = ct.chainage_m
    for ax, q in zip(axes[:, 0], panels):
        diff, sig = units.m_to_mm(getattr(d, f"{q}_m")), units.m_to_mm(getattr(d, f"sigma_{q}_m"))
        ax.fill_between(x, -k * sig, k * sig, color="0.85", lw=0, label=f"+-{k:g} sigma")
        ax.plot(x, diff, lw=0.8, color="C0", label="B - A")
        for s in (s for s in ct.comparison.stretches if s.quantity == q):
            ax.axvspan(ct.chainage_at(s.start_m), ct.chainage_at(s.end_m), color="C3", alpha=0.25, lw=0)
        ax.axhline(0.0, color="0.4", lw=0.5)
        ax.set_ylabel(f"{q} B - A [mm]")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("chainage of A [m]")
    axes[0, 0].set_title(f"B = {ct.b_path.parent.name}/{ct.b_path.name} minus A = "
                         f"{ct.a_path.parent.name}/{ct.a_path.name}")
    fig.tight_layout()
    try:
        write_with(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)
