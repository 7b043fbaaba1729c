"""A scripted simulated session whose instrument is noisier than the project's a priori sigmas
(sigma0 about 2): the fix sigmas carry the setups' covariance scaled by sigma0^2."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from rich.console import Console

from session_project import make_project

SCRIPT = "fix\nmove\nfix\nstation\nmove\nfix\nstation\nmove\nfix\nend\n"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from survey.commands.survey import simulated_world
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.session.script import parse_script
    from survey.store import ProjectStore
    from trolley.resection import InstrumentSigmas

    root = tmp_path_factory.mktemp("overlap")
    make_project(root, length_m="180.0")
    console = Console(stderr=True, record=True, width=400)
    with ProjectStore.open(root / "t1") as st:
        # the a priori sigmas half the twin's noise (0.5", 0.6 mm): sigma0 about 2 in every setup
        s = st.settings()
        sig = s.instrument
        st.set_settings(replace(s, instrument=InstrumentSigmas(sig.direction_rad / 2, sig.zenith_rad / 2,
                                                               sig.distance_m / 2, sig.distance_scale / 2)))
        world = simulated_world(st, 25.0)
        FieldSession(st, "noisy", SessionConfig(script=parse_script(SCRIPT), out_dir=root / "out"),
                     world=world, console=console).run()
    return root, " ".join(console.export_text().split())


def test_fix_sigmas_carry_the_setup_covariance_scaled_by_sigma0(session):
    # sigma^2 = fix sigma^2 + sigma0^2 x (the a priori setup covariance carried to the fix), by hand:
    # E moves by dN and N by -dE per radian of orientation
    from survey.store import ProjectStore

    root, text = session
    with ProjectStore.open(root / "t1") as st:
        rec = st.session("noisy")
        sig = rec.meta.fix_sigma_m
        setups = {s.setup_id: s for s in st.station_setups(rec.session_id)}
        fixes = st.fixes(rec.session_id)
    assert len(setups) == 3 and len(fixes) >= 6
    assert all(1.5 < s.sigma0 < 3.0 for s in setups.values())  # the instrument twice as noisy as its a priori
    for fx in fixes:
        s = setups[fx.setup_id]
        c = s.covariance * s.sigma0**2
        de, dn = fx.e_m - s.station_enh_m[0], fx.n_m - s.station_enh_m[1]
        var_e = sig**2 + c[0, 0] + 2 * dn * c[0, 3] + dn**2 * c[3, 3]
        var_n = sig**2 + c[1, 1] - 2 * de * c[1, 3] + de**2 * c[3, 3]
        var_h = sig**2 + c[2, 2]
        np.testing.assert_allclose([fx.sigma_e_m, fx.sigma_n_m, fx.sigma_h_m], np.sqrt([var_e, var_n, var_h]),
                                   rtol=1e-12)
    # the crew is told
    for s in setups.values():
        assert f"scaled by sigma0^2 = {s.sigma0 ** 2:.2f}" in text


class _Instrument:
    """The total station as far as giving it a station goes (no port: the session is over)."""

    def set_station(self, *args) -> None:
        pass

    def angle(self):
        return 0.0, 1.5707963

    def set_orientation(self, *args) -> None:
        pass

    def set_reflector_height(self, *args) -> None:
        pass


def test_a_resumed_session_restores_the_scaled_setup_covariance(session):
    # on resume the setup comes from the store (a priori covariance, sigma0, dof): the next fix from
    # it must carry the sigma an uninterrupted session gives it, the covariance scaled by sigma0^2
    from survey.session.fieldsession import FieldSession, SessionConfig
    from survey.store import ProjectStore

    root, _ = session
    with ProjectStore.open(root / "t1") as st:
        fs = FieldSession(st, "noisy", SessionConfig(script=None, live=False), console=Console(file=None),
                          resume=True)
        fs.rec = st.session("noisy")
        fs.ts = _Instrument()
        fs.station_setup()
        last = st.fixes(fs.rec.session_id)[-1]
        assert last.setup_id == fs.setup_id
        np.testing.assert_allclose(fs.fix_sigmas([last.e_m, last.n_m, last.h_m]),
                                   [last.sigma_e_m, last.sigma_n_m, last.sigma_h_m], rtol=1e-12)
