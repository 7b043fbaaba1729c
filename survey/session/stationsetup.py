"""Station setups of a field session: the free station on CPIII, station changes, the overlap check.

A mixin of :class:`survey.session.fieldsession.FieldSession` (it uses the session's store, total
station, world, console and keys). The resection is ``trolley/resection.py``; the residual table
is ``survey.commands.project.resection_table``.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from survey.session.errors import SessionAbort
from survey.store import FixRecord, setup_rows
from rich.markup import escape


#: largest sigma0 a scripted station setup is accepted with: sigma0^2 dof follows chi-square with
#: dof degrees of freedom when the instrument sigmas are right, and P(sigma0 > 3) is below 2e-4
#: for any dof >= 2 (a setup of 8 points, dof 20: about 1e-30), so only a gross error stops a script
SCRIPT_SIGMA0_LIMIT = 3.0


def _worst_axis(oc) -> str:
    """The axis of the largest |difference| / sigma with that ratio, and the joint length that decides:
    "H 2.58 sigma, joint 2.71"."""
    j = int(np.argmax(oc.normalized))
    return f"{'ENH'[j]} {oc.normalized[j]:.2f} sigma, joint {oc.mahalanobis:.2f}"


def overlap_kept(oc) -> bool:
    """Whether the overlap check lets the fix from the new station into the track (the live gate
    still has its say).

    Only a difference both outside the project's tolerance and beyond ``oc.sigma_limit`` in its joint
    sigma (the Mahalanobis length with the E-N-H covariance of the difference,
    ``trolley.resection.overlap_check``) is refused: then it is more than the two setups and measurements explain, one of them is wrong, and
    the filter must not average the two positions. A difference outside the tolerance but within
    the sigmas is a correct measurement (6.16 % of correct overlaps on the demo exceed 2 mm on some
    axis, benchmarks/fix_sigma/overlap_false_alarms.py): refusing the fix would not bring the setups
    within the tolerance, because every later fix
    from the new setup carries the same setup error into the track; it would only take away the one
    fix that ties the two setups together. The tolerance verdict stays in the record and on the
    sheet (OUTSIDE, red) for the client, as the systems we know report their tolerance checks and use
    the redundancy to find blunders (shared/research/anchors.md: GEDO's overdetermination, Amberg's
    tolerance page, the Swiss Trolley's blunder detection); docs/field_session.md, "Station change and
    overlap check". Without sigmas (an older record) the tolerance alone decides, as before."""
    if oc.within_tolerance:
        return True
    return bool(oc.consistent)


def overlap_verdict(oc) -> tuple[bool, str]:
    """(kept, the line the crew reads after the difference): the tolerance verdict, the sigma of the
    difference and what the two together mean (:func:`overlap_kept`)."""
    tol = f"the tolerance of {1e3 * oc.tolerance_m:.1f} mm"
    kept = overlap_kept(oc)
    if oc.consistent is None:
        return kept, f"{'within' if oc.within_tolerance else 'OUTSIDE'} {tol}"
    sig = "sigma " + " / ".join(f"{x:.2f}" for x in 1e3 * oc.sigma_enh_m) + " mm"
    limit = f"{oc.sigma_limit:.2f} joint sigma of the setups' own uncertainty ({sig}; {_worst_axis(oc)})"
    if oc.within_tolerance and oc.consistent:
        return kept, f"within {tol}, within {limit}"
    if oc.within_tolerance:
        return kept, (f"within {tol}, but beyond {limit}: more than the setups explain, check the two setups "
                      "before going on")
    if oc.consistent:
        return kept, (f"OUTSIDE {tol} but within {limit}: the tolerance is tighter than these setups can hold "
                      "(more CPIII points or shorter sightings)")
    return kept, (f"OUTSIDE {tol} and beyond {limit}: a setup or a measurement is wrong; set up again (s)")


def overlap_reason(oc) -> str:
    """The decision's reason stored with the overlap fix (after "overlap check from station k: ")."""
    if oc.consistent is None:
        return "accepted" if oc.within_tolerance else "difference outside the tolerance"
    # short: the sheet's and the report's reason columns; the sigmas have their own columns there
    within = f"{oc.sigma_limit:.2f} joint sigma ({_worst_axis(oc)})"
    if oc.within_tolerance and oc.consistent:
        return "accepted"
    if oc.within_tolerance:
        return f"accepted: within the tolerance, beyond {within}"
    if oc.consistent:
        return f"accepted: outside the tolerance, within {within}"
    return f"difference outside the tolerance and beyond {within}"


#: what each prism of a session is called in the crew's messages, and its ProjectSettings field
PRISMS = {"cpiii": ("CPIII prisms", "cpiii_prism_constant_m"),
          "trolley": ("trolley prism", "trolley_prism_constant_m")}


class StationSetupSteps:
    """Free station, station change and overlap check (mixin of ``FieldSession``)."""

    def use_prism(self, which: str) -> None:
        """Set the total station to the prism constant of ``which`` ("cpiii" or "trolley", the
        project's ``cpiii_prism_constant_m`` / ``trolley_prism_constant_m``) and read it back, before
        that prism is measured (:meth:`drivers.totalstation.TotalStation.ensure_prism_constant`:
        nothing is sent when the instrument already holds it, as set by this session).

        The two may differ (round prisms on the CPIII, a 360° prism on the trolley): measured with
        the other's constant every distance is off by the difference, 23.1 mm between those two.
        Each switch is stored as a ``prism_constant`` event.

        Raises
        ------
        SessionAbort : the instrument holds another constant after the set (it refused or ignored
            it); the message names the instrument, the constant expected and the one read.
        GeoComError, DeviceError : a call failed after its retries (the caller's handling).
        """
        import json

        from drivers.totalstation import PRISM_CONSTANT_TOLERANCE_M, PrismConstantError
        from trolley import units

        label, key = PRISMS[which]
        constant = float(getattr(self.settings, key))
        before = self.ts.verified_prism_constant_m
        try:
            read = self.ts.ensure_prism_constant(constant)
        except PrismConstantError as exc:
            self._event("prism_constant_mismatch", json.dumps({"prism": which,
                                                               "expected_mm": units.m_to_mm(exc.expected_m),
                                                               "read_mm": units.m_to_mm(exc.read_m)}))
            raise SessionAbort(f"{exc}, for the {label}",
                               f"set the instrument's prism constant to {units.m_to_mm(constant):+.1f} mm by hand, or correct "
                               f"the project's ({key[:-2]}_mm, `trolley project set`), then resume the session") from None
        if before is None or abs(before - read) > PRISM_CONSTANT_TOLERANCE_M:
            self._event("prism_constant", json.dumps({"prism": which, "constant_mm": units.m_to_mm(read)}))
            self.say(f"total station: prism constant {units.m_to_mm(read):+.1f} mm for the {label} (set and read back)")

    def station_setup(self) -> None:
        """Free station on the nearest CPIII points: measure, resect, show, accept / drop / re-measure."""
        setups = [s for s in self.store.station_setups(self.rec.session_id) if s.accepted]
        if setups:
            self.setup_id = setups[-1].setup_id
            if self.world is not None:
                self._restore_simulated_instrument()
            from trolley.resection import variance_factor

            last = setups[-1]
            # scaled as when it was accepted, so the fixes after a resume carry the sigmas they would
            # have had without the interruption
            self._give_station(last.station_enh_m, last.orientation_rad, last.covariance,
                               variance_factor(last.sigma0, last.dof))
            self.say(f"station setup {self.setup_id} restored from the store")
            return
        with self.crew_busy():
            self.new_station("free station on CPIII")

    def _restore_simulated_instrument(self) -> None:
        """On resume: the simulated instrument stands where it physically stood before the crash
        (the last ``simulated_instrument`` event; the first position otherwise), not at the
        resected station, which carries the setup's errors that the fixes must keep."""
        import json

        moves = [json.loads(e.detail) for e in self.store.events(self.rec.session_id)
                 if e.kind == "simulated_instrument"]
        if moves:
            self.world.place_instrument(np.array(moves[-1]["station_enh_m"]), moves[-1]["setup"])
        self.world.quiet_instrument()

    def new_station(self, title: str) -> None:
        """Measure the nearest CPIII points, resect, let the crew decide, store, give the station."""
        from survey.commands.project import resection_table
        from trolley.resection import ResectionError, resect, suggest_point_to_drop, variance_factor

        self.screen.phase = "station setup"
        points = self._setup_points()
        config = replace(self.settings.resection_config(), model=self.polar_model())
        first = not self.store.station_setups(self.rec.session_id)
        drops = [a.text.split(None, 1)[1] for a in (self.config.script or []) if a.name == "setup"] if first else []
        exclude: list[str] = []
        candidates = points
        points, obs = self._measure_points(candidates)
        while True:
            ids = [p.point_id for p in points]
            pts = np.array([[p.e_m, p.n_m, p.h_m] for p in points])
            try:
                res = resect(ids, pts, obs, config, exclude=exclude)
            except ResectionError as exc:
                raise SessionAbort(f"station setup: {exc}", "measure more CPIII points") from None
            self.console.print(resection_table(res, title))
            if self.config.script is not None:
                while drops and drops[0] not in ids:
                    # a CPIII point of the project (checked at the start) that this setup did not measure
                    self.console.print(f"setup drop {drops.pop(0)}: not among the points measured for this setup "
                                       "(nothing to drop)", highlight=False, markup=False)
                if drops:
                    exclude.append(drops.pop(0))
                    continue
                if not res.sigma0 <= SCRIPT_SIGMA0_LIMIT:
                    # nobody looks at a script's table: a setup this far off its instrument's sigmas
                    # (a point's coordinates, the wrong prism, all pointings at one target) is not
                    # accepted; the session stops here and is stored (resume)
                    flagged = ", ".join(res.flagged_points) or "none"
                    raise SessionAbort(
                        f"station setup: sigma0 {res.sigma0:.3g} exceeds {SCRIPT_SIGMA0_LIMIT:g} (flagged points: "
                        f"{flagged}); a script does not accept it",
                        "drop the bad points with `setup drop ID` lines, or set the station up interactively "
                        "(`trolley survey resume` without --script)")
                if res.flagged_points:
                    self.say(f"station setup: flagged points {', '.join(res.flagged_points)} kept (sigma0 "
                             f"{res.sigma0:.2f}); a `setup drop ID` line leaves one out")
                choice = "a"
            else:
                # data snooping's suggestion, else the point with the largest standardized residual
                worst = suggest_point_to_drop(res) or max(
                    res.residuals, key=lambda r: r.max_standardized if np.isfinite(r.max_standardized) else -1.0).point_id
                if len(ids) - len(exclude) <= 3:
                    worst = None  # three points are the minimum
                choice = self._ask_key(f"a accept | d drop {worst or '- (3 points left)'} | m measure again", "adm")
                if choice == "d":
                    if worst:
                        exclude.append(worst)
                    continue
                if choice == "m":
                    points, obs = self._measure_points(candidates)
                    exclude = []
                    continue
            break
        if self.world is not None:
            self.world.quiet_instrument()  # the setup pointings were noisy; fixes get their own noise
        setup, rows = setup_rows(res, ids, obs, self.now(), accepted=True)
        self.setup_id = self.store.add_station_setup(self.rec.session_id, setup, rows)
        factor = variance_factor(res.sigma0, res.dof)
        self._give_station(res.station_enh_m, res.orientation_rad, res.covariance, factor)
        self.say(f"station accepted (sigma0 {res.sigma0:.2f}); the total station has its station and orientation")
        if factor > 1.0:
            # the crew should know the setup and the instrument are weaker than its sigmas promise
            self.say(f"sigma0 above 1: the setup's covariance and the measurement's are scaled by sigma0^2 = "
                     f"{factor:.2f} in the sigma of every fix from this station")

    def _setup_points(self):
        pts = self.store.cpiii_points()
        if len(pts) < 3:
            raise SessionAbort("the project has fewer than 3 CPIII points",
                               f"import them with `trolley project import-cpiii FILE --project "
                               f"{self.store.info().name}`")
        if self.world is not None:
            st = self.world.station_enh_m
        elif self.last_fix is not None:  # a station change: near the trolley
            st = np.array([self.last_fix.e_m, self.last_fix.n_m, self.last_fix.h_m])
        elif self._design is not None:  # the first setup: near the start of the design, where the trolley starts
            d = self._design.evaluate(np.array([self._design.start_chainage_m]))
            st = np.array([float(np.ravel(d.E_m)[0]), float(np.ravel(d.N_m)[0])])
        else:
            st = np.array([pts[0].e_m, pts[0].n_m, pts[0].h_m])
        d = [math.hypot(p.e_m - st[0], p.n_m - st[1]) for p in pts]
        order = np.argsort(d)[: self.config.setup_points]
        return [pts[i] for i in order]

    def _measure_points(self, points):
        """Measure each point; a point the instrument cannot measure (prism blocked, no target) is
        skipped: by the crew's choice (``s``; ``m`` tries it again), or at once in a script. At
        least 3 points must remain. Returns the points measured and their observations."""
        from drivers.geocom import GeoComError
        from drivers.serialport import DeviceError
        from trolley.resection import PolarObservations

        hz, v, sd, done = [], [], [], []
        for p in points:
            while True:
                if self.world is not None:
                    self.world.aim_at_point((p.e_m, p.n_m, p.h_m))
                elif self.config.script is None:
                    self._ask_key(f"aim at {p.point_id} and press Enter", "\r\n")
                try:
                    self.use_prism("cpiii")
                    self.ts.fine_adjust()
                    m = self.ts.measure()
                except (GeoComError, DeviceError) as exc:
                    self.say(f"  {p.point_id} not measured: {exc}")
                    if self.config.script is None and self._ask_key(
                            f"s skip {p.point_id} | m measure it again", "sm") == "m":
                        continue
                    self._event("setup_point_skipped", f"{p.point_id}: {exc}")
                    m = None
                break
            if m is None:
                continue
            self.console.print(f"  {escape(str(p.point_id))}: Hz {m.hz_rad:.6f} rad, V {m.v_rad:.6f} rad, {m.slope_m:.4f} m",
                               highlight=False)
            hz.append(m.hz_rad)
            v.append(m.v_rad)
            sd.append(m.slope_m)
            done.append(p)
        if len(done) < 3:
            raise SessionAbort(f"station setup: only {len(done)} of {len(points)} CPIII points could be measured "
                               "(3 are needed)", "check the prisms and the lines of sight, then resume")
        return done, PolarObservations(np.array(hz), np.array(v), np.array(sd))

    def _grid_scale(self) -> float | None:
        """Grid distance / ground distance of the total station's measurements: the project CRS's
        combined scale (point scale x height reduction) at the CPIII centroid, or None (the polar
        model's own). The simulated twin measures in the grid itself: None."""
        if self.world is not None:
            return None
        if not hasattr(self, "_grid_scale_value"):
            grid = self.store.site_grid()
            self._grid_scale_value = None if grid is None else grid.combined_scale
        return self._grid_scale_value

    def polar_model(self):
        """The polar model of this session's total-station readings (``trolley.resection.PolarModel``),
        one for the station setups and the fixes: the project's, with the CRS's combined scale when
        there is a CRS. The simulated twin measures grid distances without curvature or refraction,
        so a simulated session takes grid scale 1 and no curvature, whatever the project says."""
        model = self.settings.resection_config(self._grid_scale()).model
        if self.world is not None:
            model = replace(model, curvature_refraction=False, grid_scale=1.0)
        return model

    def grid_coordinates(self, m) -> tuple[float, float, float]:
        """Grid E, N, H of a prism measurement, from its readings (Hz, V, slope distance) by the
        setup's polar model (:func:`trolley.resection.point_from_observation`).

        The circle reads grid azimuths once the station is given (:meth:`_give_station`), so the
        orientation is 0 here. The instrument's own coordinates (TMC_GetCoordinate) are not used:
        they are computed with ground distances and hold curvature and refraction only if the
        instrument is set so, while the resection took both from this model. Taken from them (and
        reduced to the grid only with a CRS, not by the project's own grid scale), a fix 250 m away
        with grid scale 1.00004 and no CRS was 10 mm short and 4.3 mm low
        (``tests/test_session_devices.py::test_a_fix_on_real_devices_follows_the_setups_grid_scale_and_curvature``).
        """
        from trolley.resection import PolarObservations, point_from_observation

        station = getattr(self, "_station_enh_m", None)
        if station is None:
            return m.E_m, m.N_m, m.H_m
        obs = PolarObservations(m.hz_rad, m.v_rad, m.slope_m)
        e, n, h = point_from_observation(station, 0.0, obs, self.polar_model())[0]
        return float(e), float(n), float(h)

    def fix_covariance(self, enh_m, setup=None) -> np.ndarray | None:
        """(3, 3) covariance of grid E, N, H of a prism fix at ``enh_m`` measured from the current
        setup (or from ``setup``, a stored ``StationSetupRecord``), or None before a setup.

        The polar measurement's own covariance from the project's instrument sigmas (across the line
        of sight the direction sigma times the distance, along it the distance sigma, in height the
        zenith sigma times the distance) plus the setup's error carried to the fix (station position
        and orientation with their correlations), both scaled by the setup's variance factor
        (:func:`trolley.resection.fix_covariance`; docs/field_session.md, "The fix sigma and the
        station setup"). ``fix_sigma_m`` is not in it: it is the sigma of a fix whose instrument
        geometry is not known (fixes.csv's default, the planning budget).
        """
        from trolley.resection import fix_covariance, variance_factor

        if setup is not None:
            cov, station = setup.covariance, setup.station_enh_m
            factor = variance_factor(setup.sigma0, setup.dof)
        else:
            cov = getattr(self, "_setup_covariance", None)
            station = getattr(self, "_station_enh_m", None)
            factor = getattr(self, "_setup_factor", 1.0)
        if cov is None or station is None:
            return None
        return fix_covariance(self.settings.instrument, cov, station, np.asarray(enh_m, dtype=float),
                              self.polar_model(), factor)[0]

    def fix_sigmas(self, enh_m) -> tuple[float, float, float]:
        """1-sigma of grid E, N, H of a prism fix at ``enh_m`` from the current setup: the diagonal of
        :meth:`fix_covariance`, stored with the fix (the covariances between the axes are computed
        again from its setup when the session is exported, ``ProjectStore.fix_covariances``); the
        session's ``fix_sigma_m`` per axis before a setup.

        All fixes of one setup share its error, and the engine takes fixes as independent: these
        sigmas make each fix honest on its own, not the average of several fixes of one setup.
        """
        cov = self.fix_covariance(enh_m)
        if cov is None:
            s = float(self.rec.meta.fix_sigma_m)
            return s, s, s
        e, n, h = np.sqrt(np.diag(cov))
        return float(e), float(n), float(h)

    def _give_station(self, station_enh_m, orientation_rad: float, covariance=None, factor: float = 1.0) -> None:
        """TMC_SetStation, then orient the circle so that it reads grid azimuths; ``covariance``, the
        setup's a priori (E, N, H, orientation) covariance, and ``factor``, its variance factor, go
        into the sigma of every fix from it."""
        self._station_enh_m = np.asarray(station_enh_m, dtype=float).copy()
        self._setup_covariance = None if covariance is None else np.asarray(covariance, dtype=float).copy()
        self._setup_factor = float(factor)
        e, n, h = (float(x) for x in station_enh_m)
        self.ts.set_station(e, n, h, 0.0)
        hz, _ = self.ts.angle()
        self.ts.set_orientation(float((hz + orientation_rad) % (2 * math.pi)))
        self.ts.set_reflector_height(0.0)

    def station_change(self) -> bool:
        """Set up the instrument anew; the prism at this stop measured from both stations is the
        overlap check. False while the trolley moves."""
        standing, _, dist = self.motion()
        if not standing:
            if self.config.script is None:
                self.say("station change: stop the trolley first")
            return False
        if self._fix_distance_pending:  # resumed: the odometer data up to the last fix are not in yet
            if self.config.script is None:
                self.say("station change: waiting for the odometer data up to the last fix; press s again")
            return False
        with self.crew_busy():
            return self._station_change(dist)

    def _station_change(self, dist: float) -> bool:
        from drivers.geocom import GeoComError
        from drivers.serialport import DeviceError
        from survey.fieldrecord import stored_fix_covariance
        from trolley.resection import overlap_check

        import json

        sid = self.rec.session_id
        k = sum(1 for s in self.store.station_setups(sid) if s.accepted)
        # a station change interrupted by a crash (resume): its steps already stored are not repeated
        resumed, self._station_resumed = self._station_resumed, None
        if resumed is not None and resumed == k:
            k -= 1  # its new setup was stored: go on with the overlap check
            self.say(f"station change: station {k + 1} was set up before the interruption")
        else:
            if self.world is not None:
                here = self.chainage_now(dist)
                self.world.move_instrument(k, here if np.isfinite(here) else dist)
                e, n, h = self.world.station_enh_m
                self._event("simulated_instrument", json.dumps({"setup": k, "station_enh_m": [e, n, h]}))
                self.say(f"(simulation: the instrument now stands at E {e:.3f} N {n:.3f} H {h:.3f})")
            self.say(f"station change: setting up station {k + 1}")
            if resumed != k + 1:  # stored once, also when the crash came during the setup
                self._event("station_change", f"setup {k + 1}")
            self.new_station(f"station {k + 1} on CPIII")
        first = self.last_fix
        if first is None or abs(dist - self.last_fix_distance_m) > 0.01 or first.setup_id == self.setup_id:
            return True
        if any(f.setup_id == self.setup_id and f.reason.startswith("overlap check") for f in self.store.fixes(sid)):
            return True  # measured (and decided) before the interruption
        t = self.now()
        if self.world is not None:
            self.world.aim_at_prism(t)
        try:
            self.use_prism("trolley")
            self.ts.fine_adjust()
            m = self.ts.measure()
        except (GeoComError, DeviceError) as exc:
            self.say(f"overlap check not measured: {exc}")
            return True
        here = self.grid_coordinates(m)
        sig_new = self.fix_sigmas(here)
        # each position's covariance holds its measurement and its own setup carried to the stop, with
        # the sigmas it is stored with (the old fix's as stored), so the field record recomputes the same
        setup_of = {s.setup_id: s for s in self.store.station_setups(sid)}
        old = [first.e_m, first.n_m, first.h_m]
        oc = overlap_check(first.point, old, list(here), self.settings.overlap_tolerance_m,
                           stored_fix_covariance(self.settings, old, (first.sigma_e_m, first.sigma_n_m, first.sigma_h_m),
                                                 setup_of.get(first.setup_id)),
                           stored_fix_covariance(self.settings, here, sig_new, setup_of.get(self.setup_id)))
        d = oc.difference_enh_mm
        kept, verdict = overlap_verdict(oc)
        self.say(f"overlap check at {first.point}: new - old station E {d[0]:+.2f} N {d[1]:+.2f} H {d[2]:+.2f} mm, "
                 f"{verdict}")
        fix = FixRecord(t, f"FIX{len(self.store.fixes(self.rec.session_id)) + 1:03d}", *here, *sig_new,
                        setup_id=self.setup_id)
        v = self._live_verdict(fix)
        ok = kept and (v is None or bool(v.accepted))
        reason = f"overlap check from station {k + 1}: " + (v.reason if kept and not ok else overlap_reason(oc))
        fix_id = self.store.add_fix(self.rec.session_id, replace(fix, accepted=ok, reason=reason))
        self.say(f"overlap fix {fix.point} {'accepted' if ok else 'rejected'} ({reason})")
        if ok:
            self._accepted(replace(fix, fix_id=fix_id, accepted=True, reason=reason), dist)
        return True
