"""The symbolic derivation behind trolley.budget (docs/budget_derivation.md), redone with sympy.

From the model of Jiang 2017 Eq. 17-19 and 30-31 alone: the forward covariance A(t), the
covariance C(t) of r(t) with r(T) and the innovation variance V; the smoothed variance
A - C^2/V; the printed Eq. 40, 44, 45 compared with it; the cancellation-free numerators used by
trolley.budget.variance_sources.
"""
import numpy as np
import pytest

sp = pytest.importorskip("sympy")

from trolley import budget as B  # noqa: E402

p, s2, pa, q, pb, v, T, t, tau = sp.symbols("p_r sigma_r2 p_a q p_b v T t tau", positive=True)


def _model():
    Av = sp.Matrix([[0, v, 0], [0, 0, -1], [0, 0, 0]])
    G = sp.Matrix([0, 1, 0])
    Phi = lambda s: (Av * s).exp()  # noqa: E731  Eq. 31
    P0 = sp.diag(p, pa, pb)  # Eq. 32: after the fix at t=0
    Pf = lambda s: sp.simplify(Phi(s) * P0 * Phi(s).T + sp.integrate(  # noqa: E731  Eq. 30
        Phi(s - tau) * G * q * G.T * Phi(s - tau).T, (tau, 0, s)))
    A = sp.expand(sp.cancel(Pf(t)[0, 0]))
    C = sp.expand(sp.cancel((Phi(T - t) * Pf(t))[0, 0]))  # Cov(x(T), x(t)) = Phi(T-t) P_f(t)
    V = sp.expand(sp.cancel(Pf(T)[0, 0] + s2))
    return A, C, V


A, C, V = _model()
SMOOTHED = A - C**2 / V


def test_model_quantities_match_trolley_budget():
    f = sp.lambdify((t, T, v, p, s2, pa, q, pb), (A, C, V))
    rng = np.random.default_rng(1)
    for _ in range(20):
        args = (rng.uniform(0, 50), 50.0, rng.uniform(0.5, 2), 1e-7, 2e-7, 1e-5, 1e-10, 1e-13)
        c = B.ChannelParameters(*map(np.asarray, args[3:]))
        ours = B._acv(args[0], args[1], args[2], c)
        for a, b in zip(f(*args), ours):
            assert b == pytest.approx(float(a), rel=1e-12)


def _D():
    return 12 * p + 12 * s2 + 12 * pa * v**2 * T**2 + 4 * q * v**2 * T**3 + 3 * pb * v**2 * T**4


def _printed_40_45(sign_last, last_q2):
    D = _D()
    N1 = (12 * p + 12 * s2 + 12 * pa * v**2 * (2 * t * T - t**2) + 4 * q * v**2 * (3 * t**2 * T - 2 * t**3)
          + 3 * pb * v**2 * (2 * t**2 * T**2 - t**4))
    N2 = 12 * p + 12 * s2 + 12 * pa * v**2 * t**2 + 4 * q * v**2 * t**3 + 3 * pb * v**2 * t**4
    last = v**4 * t**2 * (t - T) ** 2 * (last_q2 + 9 * pa * pb * T**2 + 3 * q * T * (4 * pa + pb * t * T)) / (3 * D)
    return p - p * N1 / D + (s2 * N2 - 12 * s2**2) / D + sign_last * last


def test_printed_eq40_and_eq45_differ_and_the_corrected_form_is_exact():
    printed_q2 = q**2 * t * (t - 4 * T)
    eq40 = _printed_40_45(-1, printed_q2)
    eq45 = _printed_40_45(+1, printed_q2)
    assert sp.simplify(eq40 - SMOOTHED) != 0
    # Eq. 45 is off only by the sign of the sigma_w^4 term
    diff45 = sp.factor(sp.simplify(eq45 - SMOOTHED))
    assert sp.simplify(diff45 - 2 * q**2 * v**4 * t**3 * (t - T) ** 2 * (t - 4 * T) / (3 * _D())) == 0
    corrected = _printed_40_45(+1, q**2 * t * (4 * T - t))
    assert sp.simplify(corrected - SMOOTHED) == 0


def test_printed_eq44_is_exact():
    D3 = 3 * p + 3 * s2 + 3 * pa * v**2 * T**2 + q * v**2 * T**3
    eq44 = (p - p * (3 * p + 3 * s2 + 3 * pa * v**2 * (2 * t * T - t**2) + q * v**2 * (3 * t**2 * T - 2 * t**3)) / D3
            + (s2 * (3 * p + 3 * s2 + 3 * pa * v**2 * t**2 + v**2 * q * t**3) - 3 * s2**2) / D3
            - q * v**4 * t**2 * (t - T) ** 2 * (q * t * (t - 4 * T) - 12 * pa * T) / (12 * D3))
    assert sp.simplify(eq44 - SMOOTHED.subs(pb, 0)) == 0


def test_cancellation_free_numerators():
    u = T - t
    assert sp.expand((V - C) - (s2 + v**2 * (pa * T * u + q * u * (2 * T**2 + 2 * T * t - t**2) / 6
                                             + pb * T**2 * u * (T + t) / 4))) == 0
    assert sp.expand((t * V - C * T) - (t * s2 - u * p + v**2 * (q * T * t * u * (2 * T - t) / 6
                                                                   + pb * t * T**3 * u / 4))) == 0
    assert sp.expand((t**2 * V - C * T**2) - (t**2 * s2 - (T**2 - t**2) * p
                                               - v**2 * (pa * t * T**2 * u + q * T**2 * t**2 * u / 6))) == 0
