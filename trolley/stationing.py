"""Station equations: the stationing a drawing shows against the distance along the alignment.

A design alignment has an *internal* station (its start station plus the distance along it; the
LandXML ``station`` type) and a *drawing* stationing that may jump at station equations
(km-post breaks, re-chainaged sections). An equation at internal station ``s_e`` says: the
stationing behind it runs up to ``back`` (when given), the one ahead of it starts at ``ahead``
and increases (or decreases) with the distance. Before the first equation the drawing
stationing is the internal one. A forward jump (ahead > back) leaves stations that exist nowhere
on the track; a backward jump makes some stations occur twice.

See ``docs/conventions.md``, "Design geometry", for how outputs use it.

References
----------
LandXML-1.2 schema, http://www.landxml.org/schema/LandXML-1.2/LandXML-1.2.xsd: ``StaEquation``
(staInternal, staAhead, staBack, staIncrement) and the ``station`` simple type ("the internal
station value where no station equations are applied").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["StationEquation", "Stationing", "StationNotFound"]


class StationNotFound(ValueError):
    """A drawing station that lies in no region (a gap left by a forward jump), or only behind
    the stations before it. ``index`` is its position in the sequence given."""

    def __init__(self, index: int, station_m: float) -> None:
        super().__init__(f"station {station_m!r} (no. {index + 1}) is in no part of the drawing "
                         f"stationing at or after the stations before it")
        self.index = index
        self.station_m = station_m


@dataclass(frozen=True)
class StationEquation:
    """One station equation.

    Attributes
    ----------
    internal_m : internal station where it applies, m.
    ahead_m : drawing station just ahead of it, m.
    back_m : drawing station just behind it, m (None: not given).
    increasing : stations ahead increase with the distance (False: they decrease).
    """

    internal_m: float
    ahead_m: float
    back_m: float | None = None
    increasing: bool = True


class Stationing:
    """Drawing stationing of an alignment from its station equations (vectorised).

    Parameters
    ----------
    start_internal_m, end_internal_m : internal stations of the alignment start and end, m.
    equations : station equations, in increasing internal station, from the alignment start
        (an equation there renumbers the start) to before its end.

    Attributes
    ----------
    equations : tuple of the equations.
    region_start_m : (k+1,) internal station where each region begins (the start, then each
        equation).
    region_station_m : (k+1,) drawing station at the beginning of each region.
    region_sign : (k+1,) +1 or -1, the direction of the drawing stationing in each region.

    Raises
    ------
    ValueError
        An equation outside the alignment, or equations not in increasing internal station.
    """

    def __init__(self, start_internal_m: float, end_internal_m: float,
                 equations: Sequence[StationEquation] = ()) -> None:
        eqs = tuple(equations)
        self.start_internal_m = float(start_internal_m)
        self.end_internal_m = float(end_internal_m)
        for i, e in enumerate(eqs):
            if not self.start_internal_m <= e.internal_m < self.end_internal_m:
                raise ValueError(f"station equation {i + 1}: internal station {e.internal_m!r} is "
                                 f"not inside the alignment ({self.start_internal_m!r} .. "
                                 f"{self.end_internal_m!r})")
            if i and not e.internal_m > eqs[i - 1].internal_m:
                raise ValueError(f"station equation {i + 1}: internal station {e.internal_m!r} does "
                                 f"not follow the previous one ({eqs[i - 1].internal_m!r})")
        self.equations = eqs
        self.region_start_m = np.array([self.start_internal_m] + [e.internal_m for e in eqs])
        self.region_station_m = np.array([self.start_internal_m] + [e.ahead_m for e in eqs])
        self.region_sign = np.array([1.0] + [1.0 if e.increasing else -1.0 for e in eqs])
        self.region_end_m = np.append(self.region_start_m[1:], self.end_internal_m)

    def station(self, internal_m) -> np.ndarray:
        """Drawing station at internal stations (beyond the ends the end regions continue).

        At an equation the station ahead is returned.
        """
        s = np.asarray(internal_m, dtype=float)
        k = np.clip(np.searchsorted(self.region_start_m, s, side="right") - 1, 0, None)
        return self.region_station_m[k] + self.region_sign[k] * (s - self.region_start_m[k])

    def back_station(self, i: int) -> float:
        """Drawing station just behind equation ``i`` (0-based), as the region before it runs."""
        return float(self._region_end_station()[i])

    def _region_end_station(self) -> np.ndarray:
        """Drawing station at the end of each region."""
        return self.region_station_m + self.region_sign * (self.region_end_m - self.region_start_m)

    def internal(self, station_m: float, region: int) -> float:
        """Internal station of drawing station ``station_m`` in region ``region``."""
        return float(self.region_start_m[region]
                     + self.region_sign[region] * (station_m - self.region_station_m[region]))

    def internal_of(self, stations_m, tol_m: float = 1e-3) -> np.ndarray:
        """Internal stations of drawing stations given in order along the alignment.

        Each station is taken in the first region, at or after the previous station's region,
        whose drawing stations hold it (within ``tol_m``) and that does not put it behind the
        previous one: a station that occurs twice (a backward jump) resolves by its order.
        Stations before the start or beyond the end continue the end regions.

        Raises
        ------
        StationNotFound
            A station in a gap left by a forward jump, or one only behind its predecessor.
        """
        first, last = self.region_station_m, self._region_end_station()
        lo, hi = np.minimum(first, last), np.maximum(first, last)
        n = len(first)
        out = np.empty(len(stations_m))
        region, prev = 0, -np.inf
        for i, v in enumerate(np.asarray(stations_m, dtype=float)):
            for k in range(region, n):
                before = k == 0 and self.region_sign[0] * (v - first[0]) < 0
                after = k == n - 1 and self.region_sign[k] * (v - last[k]) > 0
                if (lo[k] - tol_m <= v <= hi[k] + tol_m) or before or after:
                    s = self.internal(v, k)
                    if s >= prev - tol_m:
                        break
            else:
                raise StationNotFound(i, float(v))
            region, prev, out[i] = k, s, s
        return out
