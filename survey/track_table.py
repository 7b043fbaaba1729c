"""The survey report in display units: columns of the Track sheet / CSV and the report bundle.

One place decides each column's header (with unit and sign convention), its CSV name, its
display unit (m, mm, mm/m, converted with trolley/units.py) and its number format, so the
workbook, the CSV and the plots agree.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trolley import units
from trolley.bands import BANDS
from trolley.stationing import Stationing
from trolley.tolerances import Defect, Limit, ToleranceSet
from trolley.trackgeometry import ColumnStats, GeometryConfig, TrackGeometry, nearest_stations

from survey.fieldrecord import FieldRecord
from survey.track_reader import FixRow, SurveyInfo

#: display unit -> (converter from SI, number format, digits kept in files)
UNIT_FORMATS = {
    "m": (lambda x: np.asarray(x, dtype=float), "0.0000", 6),
    "mm": (units.m_to_mm, "0.00", 4),
    "mm/m": (units.ratio_to_mm_per_m, "0.000", 5),
}
#: display unit -> back to SI (the inverse of UNIT_FORMATS' conversion, the tolerance files' own)
FROM_DISPLAY = {"m": lambda x: np.asarray(x, dtype=float), "mm": units.mm_to_m, "mm/m": units.mm_per_m_to_ratio}
#: chainage shown as km+m, e.g. 1+234.500 (the value stays the chainage in metres)
KM_FORMAT = '0"+"000.000'


@dataclass(frozen=True)
class SheetColumn:
    """One column of the Track table.

    Attributes
    ----------
    key : geometry column (SI) or ``chainage_m`` / ``station_km``.
    header : sheet header, with unit and sign convention.
    csv_name : CSV header (unit in the name).
    unit : display unit ("m", "mm", "mm/m").
    number_format : Excel number format.
    """

    key: str
    header: str
    csv_name: str
    unit: str
    number_format: str

    def display(self, values: np.ndarray) -> np.ndarray:
        """SI values converted to the display unit and rounded to the digits kept in files."""
        conv, _, digits = UNIT_FORMATS[self.unit]
        return np.round(np.asarray(conv(values), dtype=float), digits)

    @property
    def kept_digits(self) -> int:
        """Decimals the files keep in the display unit, and the limits are checked on."""
        return UNIT_FORMATS[self.unit][2]

    @property
    def kept_format(self) -> str:
        """Excel number format with :attr:`kept_digits`: a peak of 1.0001 mm against 1 mm must
        not read "1.00 / 1.00" on the Defects sheet."""
        return "0." + "0" * self.kept_digits

    def kept(self, values: np.ndarray) -> np.ndarray:
        """The SI values as the files keep them (:meth:`display` and back): what the tolerances
        are checked on, so a value the sheet shows as 1.0000 mm is never a defect against 1 mm."""
        return np.asarray(FROM_DISPLAY[self.unit](self.display(values)), dtype=float)

    @property
    def shown_digits(self) -> int:
        """Decimals the sheet shows (its :attr:`number_format`)."""
        return self.number_format.rpartition(".")[2].count("0")

    @property
    def close_format(self) -> str:
        """Excel number format of a value beyond its limit by less than half the last shown digit
        (:meth:`close_to_limit`): the shown digits, and up to :attr:`kept_digits` where they are
        not zero (1.004 mm against 1 mm reads "1.004", not a red "1.00"). Also the limits' format:
        a limit of 0.6667 mm/m reads "0.6667", not "0.667"."""
        return self.number_format + "#" * max(self.kept_digits - self.shown_digits, 0)

    def close_to_limit(self, values: np.ndarray, lower: float, upper: float) -> np.ndarray:
        """Mask of the display ``values`` beyond [lower, upper] (in the column's unit, as
        :func:`limit_in_column` gives it) by at most half the last shown digit: rounded to the
        shown digits they could read as the limit itself, so they are shown with
        :attr:`close_format`. (The verdict is taken on the kept digits, as the CSV holds them;
        only how the sheet shows the value changes.)"""
        v = np.asarray(values, dtype=float)
        half = 0.5 * 10.0 ** -self.shown_digits * (1 + 1e-9)
        with np.errstate(invalid="ignore"):
            return ((v > upper) & (v - upper <= half)) | ((v < lower) & (lower - v <= half))

    def text(self, value: float, lower: float = -np.inf, upper: float = np.inf) -> str:
        """``value`` (display unit) as the sheet shows it, for the PDF: the shown digits, or up to
        the kept digits where :meth:`close_to_limit` (trailing zeros beyond the shown digits
        dropped, as :attr:`close_format` does in Excel). "" when not finite."""
        if not np.isfinite(value):
            return ""
        if not self.close_to_limit(np.array([value]), lower, upper)[0]:
            return f"{value:.{self.shown_digits}f}"
        return limit_text(value, self.shown_digits, self.kept_digits)


def _g(x: float) -> str:
    return f"{x:g}"


def _tags(config: GeometryConfig) -> tuple[str, str, str]:
    """Short sign tags for the headers: lateral ("+right"), cant ("+left high"), versine."""
    lat = "+right" if config.lateral_sign == "right" else "+left"
    cant = "+left high" if config.cant_sign == "left_high" else "+right high"
    vs = "centre-chord" if config.versine_sign == "centre_minus_chord" else "chord-centre"
    return lat, cant, vs


def conventions(config: GeometryConfig) -> list[tuple[str, str]]:
    """The sign conventions in force, as (name, text) lines for the Summary sheet.

    Each says whether it is the default (docs/track_geometry.md; FORMATS.md section 2 for
    lateral and cant), so a non-default choice is visible on the sheet, never silent.
    """
    dflt = GeometryConfig()

    def state(name: str) -> str:
        v = getattr(config, name)
        return f"setting {name} = {v}" + (" (default)" if v == getattr(dflt, name) else " (NOT the default)")

    side = "RIGHT" if config.lateral_sign == "right" else "LEFT"
    rail = "LEFT" if config.cant_sign == "left_high" else "RIGHT"
    L = _g(config.versine_chord_m)
    if config.versine_sign == "centre_minus_chord":
        v = f"v(s) = z(s) - (z(s-L/2) + z(s+L/2))/2, L = {L} m (centre minus chord)"
    else:
        v = f"v(s) = (z(s-L/2) + z(s+L/2))/2 - z(s), L = {L} m (chord minus centre)"
    return [
        ("Lateral sign", f"+ to the {side} facing increasing chainage: lateral dev, slew, horizontal "
                         f"versines, lateral chords, alignment bands; {state('lateral_sign')}"),
        ("Cant sign", f"+ when the {rail} rail is higher: cant, design cant, cant dev, twist; "
                      f"{state('cant_sign')}"),
        ("Versine sign", f"{v}; z = height (V) or offset along the lateral axis (H); "
                         f"{state('versine_sign')}"),
        ("Vertical sign", "+ up: vertical dev, lift, vertical versines and chords, level bands (fixed)"),
    ]


def sheet_columns(config: GeometryConfig) -> list[SheetColumn]:
    """The Track table columns for a geometry configuration, in sheet order."""
    lat, cant, vs = _tags(config)
    L, tb, gb = _g(config.versine_chord_m), _g(config.twist_base_m), _g(config.gauge_rate_base_m)
    cols = [
        ("chainage_m", "Chainage [m]", "chainage_m", "m", "0.000"),
        ("station_km", "Station [km+m]", "station_km_m", "m", KM_FORMAT),
        ("E_m", "E [m]", "E_m", "m", "0.0000"), ("N_m", "N [m]", "N_m", "m", "0.0000"),
        ("H_m", "H [m]", "H_m", "m", "0.0000"),
        ("sigma_E_m", "σE [mm]", "sigma_E_mm", "mm", "0.00"),
        ("sigma_N_m", "σN [mm]", "sigma_N_mm", "mm", "0.00"),
        ("sigma_H_m", "σH [mm]", "sigma_H_mm", "mm", "0.00"),
        ("design_E_m", "Design E [m]", "design_E_m", "m", "0.0000"),
        ("design_N_m", "Design N [m]", "design_N_m", "m", "0.0000"),
        ("design_H_m", "Design H [m]", "design_H_m", "m", "0.0000"),
        ("lateral_dev_m", f"Lateral dev [mm] {lat}", "lateral_dev_mm", "mm", "0.00"),
        ("vertical_dev_m", "Vertical dev [mm] +up", "vertical_dev_mm", "mm", "0.00"),
        ("sigma_lateral_m", "σ lateral [mm]", "sigma_lateral_mm", "mm", "0.00"),
        ("sigma_vertical_m", "σ vertical [mm]", "sigma_vertical_mm", "mm", "0.00"),
        ("slew_m", f"Slew [mm] {lat}", "slew_mm", "mm", "0.00"),
        ("lift_m", "Lift [mm] +up", "lift_mm", "mm", "0.00"),
        ("gauge_m", "Gauge [mm]", "gauge_mm", "mm", "0.00"),
        ("gauge_dev_m", f"Gauge dev [mm] (nominal {units.m_to_mm(config.nominal_gauge_m):g})", "gauge_dev_mm", "mm", "0.00"),
        ("gauge_rate_m_per_m", f"Gauge rate {gb} m [mm/m]", "gauge_rate_mm_per_m", "mm/m", "0.000"),
        ("cant_m", f"Cant [mm] {cant}", "cant_mm", "mm", "0.00"),
        ("sigma_cant_m", "σ cant [mm]", "sigma_cant_mm", "mm", "0.00"),
        ("design_cant_m", f"Design cant [mm] {cant}", "design_cant_mm", "mm", "0.00"),
        ("cant_dev_m", f"Cant dev [mm] {cant}", "cant_dev_mm", "mm", "0.00"),
        ("twist_m", f"Twist {tb} m [mm] {cant}", "twist_mm", "mm", "0.00"),
        ("twist_rate_m_per_m", f"Twist rate {tb} m [mm/m] {cant}", "twist_rate_mm_per_m", "mm/m", "0.000"),
        ("twist_dev_m", f"Twist less design {tb} m [mm] {cant}", "twist_dev_mm", "mm", "0.00"),
        ("versine_h_m", f"Versine H {L} m [mm] {vs} {lat}", "versine_h_mm", "mm", "0.00"),
        ("design_versine_h_m", f"Design versine H {L} m [mm] {vs} {lat}", "design_versine_h_mm", "mm", "0.00"),
        ("versine_h_dev_m", f"Alignment {L} m chord [mm] {vs} {lat}", "versine_h_dev_mm", "mm", "0.00"),
        ("versine_v_m", f"Versine V {L} m [mm] {vs} +up", "versine_v_mm", "mm", "0.00"),
        ("design_versine_v_m", f"Design versine V {L} m [mm] {vs} +up", "design_versine_v_mm", "mm", "0.00"),
        ("versine_v_dev_m", f"Level {L} m chord [mm] {vs} +up", "versine_v_dev_mm", "mm", "0.00"),
    ]
    for chord, spacing in config.long_chords_m:
        tag = f"chord{chord:g}_{spacing:g}".replace(".", "p")
        cols.append((f"{tag}_lat_m", f"Chord {chord:g}/{spacing:g} m lat [mm] {lat}", f"{tag}_lat_mm", "mm", "0.00"))
        cols.append((f"{tag}_vert_m", f"Chord {chord:g}/{spacing:g} m vert [mm] +up", f"{tag}_vert_mm", "mm", "0.00"))
    for b in config.bands:
        lo, hi = BANDS[b]
        cols.append((f"align_{b}_m", f"Alignment {b} {lo:g}-{hi:g} m [mm] {lat}", f"align_{b}_mm", "mm", "0.00"))
    for b in config.bands:
        lo, hi = BANDS[b]
        cols.append((f"level_{b}_m", f"Level {b} {lo:g}-{hi:g} m [mm] +up", f"level_{b}_mm", "mm", "0.00"))
    return [SheetColumn(*c) for c in cols]


def column_values(col: SheetColumn, geometry: TrackGeometry, station_m: np.ndarray | None = None) -> np.ndarray:
    """The display values of one Track column.

    ``station_m`` is the drawing stationing of the stations (:meth:`SurveyReport.station`), shown
    in the chainage columns; None: the internal stations ``geometry.chainage_m``.
    """
    if col.key in ("chainage_m", "station_km"):
        return col.display(geometry.chainage_m if station_m is None else station_m)
    return col.display(geometry.columns[col.key])


def limit_text(value: float, shown_digits: int, kept_digits: int) -> str:
    """A limit (or a value next to one) with at least ``shown_digits`` decimals and up to
    ``kept_digits`` where they are not zero: 1 -> "1.00", 0.6667 -> "0.6667" (Excel's
    ``0.00##``)."""
    if not np.isfinite(value):
        return ""
    text = f"{value:.{kept_digits}f}"
    cut = len(text) - (kept_digits - shown_digits)
    return text[:cut] + text[cut:].rstrip("0")


def _as_written(x: float) -> float:
    """A limit converted back from SI to the unit it was written in, to 12 significant digits:
    18 mm is 0.018 m and back 18.000000000000004 mm, and the red cells of a value of exactly 18
    would depend on that last bit (the defects compare the SI values, where 18 == 18)."""
    return float(f"{x:.12g}") if np.isfinite(x) else float(x)


def limit_in_display(limit: Limit) -> tuple[float, float, str]:
    """(lower, upper, unit) of a limit in its display unit (inf stays inf)."""
    if limit.unit == "mm_per_m":
        return (_as_written(units.ratio_to_mm_per_m(limit.lower)), _as_written(units.ratio_to_mm_per_m(limit.upper)),
                "mm/m")
    return (_as_written(units.m_to_mm(limit.lower)), _as_written(units.m_to_mm(limit.upper)), "mm")


def limit_in_column(limit: Limit, column: SheetColumn) -> tuple[float, float]:
    """(lower, upper) of a limit in the unit of the column's cells (inf stays inf): a limit given
    in mm on a column shown in m (a tolerance on E_m, say) is compared and shown in m."""
    conv = UNIT_FORMATS[column.unit][0]
    return _as_written(float(conv(limit.lower))), _as_written(float(conv(limit.upper)))


def fix_chainages(geometry: TrackGeometry, fixes: list[FixRow] | None,
                  record: FieldRecord | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Chainage of the fixes the processing used and of those it or the crew rejected: the
    station nearest to each fix's E, N (:func:`trolley.trackgeometry.nearest_stations`; a fix
    farther than ``FIX_NEAR_TRACK_M`` from the surveyed track is left out).

    Parameters
    ----------
    geometry : the report's geometry (its E_m, N_m columns).
    fixes : fixes.csv's rows (None: none).
    record : the field record, whose fixes rejected in the field fixes.csv does not hold.

    Returns
    -------
    accepted_m, rejected_m : chainages, m.
    """
    rows = list(fixes or [])
    if record is not None:
        seen = {f.point for f in rows}
        rows += [f for f in record.rejected if f.point not in seen]
    if not rows:
        return np.zeros(0), np.zeros(0)
    i = nearest_stations(geometry.columns["E_m"], geometry.columns["N_m"],
                         np.array([f.E_m for f in rows]), np.array([f.N_m for f in rows]))
    acc = np.array([f.accepted for f in rows])
    s = geometry.chainage_m[np.maximum(i, 0)]
    return s[(i >= 0) & acc], s[(i >= 0) & ~acc]


@dataclass
class SurveyReport:
    """Everything the workbook, CSV and plots show.

    Attributes
    ----------
    track_csv : input file.
    geometry : computed parameters.
    columns : Track table columns.
    tolerances : tolerance set used.
    defects : exceedances.
    stats : statistics per geometry column.
    info : survey metadata (summary.json).
    fixes : fixes, or None when fixes.csv is absent.
    design_file : LandXML used, or None.
    notes : messages for the Summary sheet (e.g. why no design).
    record : the field session's record (field_record.json beside track.csv), or None.
    stationing : the design's drawing stationing (station equations), or None when the drawing
        stationing is the internal station. ``geometry.chainage_m`` (and every chainage in
        ``defects``) is the internal station, along which chords, twist bases, filters and
        sections run; every chainage shown goes through :meth:`station`.
    cov_EN : True when track.csv gave the E-N covariance (``cov_EN_mm2``) that the lateral sigma
        takes; False for a track.csv without it (taken as 0).
    absolute_checked : per station, whether its absolute parameters
        (:data:`trolley.trackgeometry.ABSOLUTE_COLUMNS`) are checked against the tolerances: the
        stations between the first and the last fix used (:func:`trolley.trackgeometry.fixed_span`);
        None: every station (no fixes.csv beside track.csv, or no fix on the track).
    """

    track_csv: Path
    geometry: TrackGeometry
    columns: list[SheetColumn]
    tolerances: ToleranceSet
    defects: list[Defect]
    stats: dict[str, ColumnStats]
    info: SurveyInfo
    fixes: list[FixRow] | None
    design_file: Path | None = None
    notes: list[str] = field(default_factory=list)
    record: FieldRecord | None = None
    stationing: Stationing | None = None
    cov_EN: bool = False
    absolute_checked: np.ndarray | None = None

    def station(self, internal_m):
        """Drawing station (what the client sees) of internal stations, m (array or float)."""
        if self.stationing is None:
            return np.asarray(internal_m, dtype=float) if np.ndim(internal_m) else float(internal_m)
        v = self.stationing.station(internal_m)
        return v if np.ndim(internal_m) else float(v)

    def defect_length_m(self, defect: Defect) -> float:
        """Length of track a defect covers, m: each of its stations stands for half a step on
        either side, but not beyond the first and last station of the survey (a defect at the
        end must not be longer than the track surveyed)."""
        s, h = self.geometry.chainage_m, 0.5 * self.geometry.step_m
        return float(min(defect.end_chainage_m + h, s[-1]) - max(defect.start_chainage_m - h, s[0]))

    @property
    def station_m(self) -> np.ndarray:
        """Drawing station of every station of the geometry, m."""
        return self.station(self.geometry.chainage_m)

    def equations(self) -> list[tuple[float, str]]:
        """The station equations inside the surveyed stretch: (internal station, text for the
        client), e.g. "station equation: 1+300.000 back = 2+300.000 ahead (jump +1000.000 m)"."""
        if self.stationing is None:
            return []
        from survey.plots import km_label

        s = self.geometry.chainage_m
        out = []
        for i, e in enumerate(self.stationing.equations):
            if s[0] < e.internal_m <= s[-1]:
                back = self.stationing.back_station(i)
                out.append((e.internal_m, f"station equation: {km_label(back, 3)} back = "
                                          f"{km_label(e.ahead_m, 3)} ahead (jump {e.ahead_m - back:+.3f} m"
                                          + ("" if e.increasing else ", stationing decreasing ahead") + ")"))
        return out

    @property
    def passed(self) -> bool:
        """True when no defect was found."""
        return not self.defects

    def unchecked_runs(self) -> list[tuple[int, int]]:
        """The runs of stations (first, last index, inclusive) whose absolute parameters are not
        checked: before the first and beyond the last fix used (:attr:`absolute_checked`); [] when
        every station is. The Track sheet greys them, the plots wash them out."""
        if self.absolute_checked is None:
            return []
        inside = np.flatnonzero(self.absolute_checked)
        n = self.absolute_checked.size
        if not inside.size:
            return [(0, n - 1)]
        return [(a, b) for a, b in ((0, int(inside[0]) - 1), (int(inside[-1]) + 1, n - 1)) if a <= b]

    @property
    def no_defects_text(self) -> str:
        """What a report without defects says of its values (the PDF's cover, the Defects sheet):
        with stations outside the outermost fixes (:attr:`absolute_checked`) not every value was
        checked, and one beyond tolerance may stand there."""
        if self.absolute_checked is None:
            return "no value beyond tolerance"
        # (the cover's line at 13 pt bold: 0.87 of the page's width)
        return "no checked value beyond tolerance (not every value was checked: see the summary's notes)"
