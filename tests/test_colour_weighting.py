"""The scatter that estimating the output weights adds to the coloured covariance.

`_weighting.weighting_spread` linearises output error's maximum-likelihood
estimator (feasible GLS: each output weighted by its own residual mean square)
and measures, on Gaussian draws with a given noise spectrum, how much the
re-estimated weights widen each parameter's spread. Here it is checked against
a brute-force Monte Carlo of the same estimator written out in the time domain
(AR(1) noise filtered sample by sample, the weights iterated to their fixed
point), on two outputs that share their parameters: one output carries slow
AR(1) noise, so its residual mean square rests on few degrees of freedom and
falls when the fit takes up noise along a slow sensitivity.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from aeroid import _colour, _weighting

N, P = 600, 3
PHI = 0.995


def _design(seed: int = 0) -> np.ndarray:
    """(N, 2, P): slow inputs on output 0, faster ones on output 1, a bias on each."""
    rng = np.random.default_rng(seed)
    g = np.zeros((N, 2, P + 2))
    for i, fc in enumerate((0.01, 0.02)):
        b, a = butter(2, fc)
        x = lfilter(b, a, rng.standard_normal(N + 300))[300:]
        g[:, 0, i] = x / x.std()
    for i, fc in enumerate((0.1, 0.3)):
        b, a = butter(2, fc)
        x = lfilter(b, a, rng.standard_normal(N + 300))[300:]
        g[:, 1, i] = x / x.std()
    g[:, :, 2] = 0.5  # a derivative seen on both outputs, a slope on the first
    g[:, 0, 2] += np.linspace(-1.0, 1.0, N)
    g[:, 0, 3] = 1.0
    g[:, 1, 4] = 1.0
    return g


def _spectrum(phi0: float) -> np.ndarray:
    """Unit-variance AR(1) on output 0 and white on output 1, on the 2N-point bins."""
    w = np.pi * np.arange(N + 1) / N
    spec = np.zeros((N + 1, 2, 2), dtype=complex)
    spec[:, 0, 0] = (1.0 - phi0**2) / np.abs(1.0 - phi0 * np.exp(-1j * w)) ** 2
    spec[:, 1, 1] = 1.0
    return spec


def _brute_force(g: np.ndarray, phi0: float, draws: int) -> np.ndarray:
    """Variance ratio, re-estimated over fixed weights, by explicit simulation."""
    rng = np.random.default_rng(12345)
    info = np.einsum("tap,taq->apq", g, g)
    fixed, free = [], []
    for _ in range(draws):
        w0 = rng.standard_normal(N)
        w0[0] /= np.sqrt(1.0 - phi0**2)
        e = np.column_stack(
            [lfilter([1.0], [1.0, -phi0], w0) * np.sqrt(1.0 - phi0**2), rng.standard_normal(N)]
        )
        b = np.einsum("tap,ta->ap", g, e)
        theta = np.linalg.solve(info.sum(0), b.sum(0))
        fixed.append(theta)
        weights = np.ones(2)
        for _ in range(200):
            resid = e - np.einsum("tap,p->ta", g, theta)
            new = N / np.sum(resid**2, axis=0)
            theta = np.linalg.solve(np.einsum("a,apq->pq", new, info), np.einsum("a,ap->p", new, b))
            if np.max(np.abs(new / weights - 1.0)) < 1e-12:
                break
            weights = new
        free.append(theta)
    return np.var(np.array(free), axis=0) / np.var(np.array(fixed), axis=0)


def test_the_spread_matches_a_brute_force_monte_carlo() -> None:
    g = _design()
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    ratio = _weighting.weighting_spread([g], [_spectrum(PHI)], m_inv, draws=4000, tol=0.0)
    brute = _brute_force(g, PHI, 4000)
    # The slow derivatives' spread more than doubles: the effect is there to be seen.
    assert np.all(brute[:2] > 2.0), brute
    # Each is a ratio of two variances over the same draws; over 4000 draws its
    # relative scatter is a few per cent (over seeds: 1-2 % here).
    np.testing.assert_allclose(ratio, brute, rtol=0.06)


def test_white_noise_adds_nothing_to_speak_of() -> None:
    # Residual mean squares of white noise are independent of the estimate (to
    # first order, Kackar & Harville), and over N samples barely move.
    g = _design()
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    ratio = _weighting.weighting_spread([g], [_spectrum(0.0)], m_inv, draws=2000)
    assert np.all(np.abs(ratio - 1.0) < 0.03), ratio


def test_the_spread_is_the_same_for_the_same_data_and_widens_the_covariance() -> None:
    g = _design()
    rng = np.random.default_rng(3)
    w = rng.standard_normal(N)
    u = np.column_stack([lfilter([1.0], [1.0, -PHI], w) * 0.1, rng.standard_normal(N)])
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    u = u - np.einsum("tap,p->ta", g, m_inv @ np.einsum("tap,ta->p", g, u))
    plain, nu = _colour.colored_covariance([g], [u], m_inv)
    first, nu1 = _colour.colored_covariance([g], [u], m_inv, estimated_weights=True)
    again, _ = _colour.colored_covariance([g], [u], m_inv, estimated_weights=True)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(nu, nu1)
    root = np.sqrt(np.diag(first) / np.diag(plain))
    # the correlations are those at fixed weights
    np.testing.assert_allclose(first, plain * root[:, None] * root[None, :], rtol=1e-12)
    assert np.any(root > 1.05), root


def test_one_output_and_directions_outside_the_fit_are_left_alone() -> None:
    g = _design()
    one = g[:, :1, [0, 1, 2, 3]]
    u = np.random.default_rng(1).standard_normal((N, 1))
    m1 = np.linalg.inv(np.einsum("tap,taq->pq", one, one))
    plain, _ = _colour.colored_covariance([one], [u], m1)
    spread, _ = _colour.colored_covariance([one], [u], m1, estimated_weights=True)
    np.testing.assert_array_equal(plain, spread)
    # a parameter no output sees (held at a bound, say): pseudo-inverse, ratio one
    held = np.concatenate([g, np.zeros((N, 2, 1))], axis=2)
    m_full = np.linalg.pinv(np.einsum("tap,taq->pq", held, held), hermitian=True)
    ratio = _weighting.weighting_spread([held], [_spectrum(PHI)], m_full, draws=200)
    assert ratio[-1] == 1.0 and np.all(np.isfinite(ratio)), ratio


def _frequency_problem(m: int = 40, n_y: int = 3, p: int = 4) -> tuple[np.ndarray, ...]:
    """Complex sensitivities, a spectrum peaked on output 0, a complex whitening."""
    rng = np.random.default_rng(7)
    w = np.linspace(0.5, 6.0, m)
    g = np.zeros((m, n_y, p), dtype=complex)
    for j in range(p):
        pole = 1.0 + j
        g[:, :, j] = (rng.standard_normal(n_y) + 1j * rng.standard_normal(n_y)) / (
            1j * w[:, None] + pole
        )
    spec = np.zeros((m, n_y, n_y), dtype=complex)
    spec[:, 0, 0] = 1.0 + 20.0 / (1.0 + ((w - 2.0) / 0.3) ** 2)  # a narrow noise peak
    spec[:, 1, 1] = 1.0
    spec[:, 2, 2] = 1.0
    spec[:, 1, 2] = 0.5j  # one output a quarter turn behind another
    spec[:, 2, 1] = -0.5j
    # in the weighted units the fit's own weighting is the identity: mean S = I
    c_inv = np.linalg.inv(np.linalg.cholesky(spec.mean(axis=0)))
    spec = c_inv @ spec @ c_inv.conj().T
    unwhiten = np.eye(n_y) + 0.3 * (
        rng.standard_normal((n_y, n_y)) + 1j * rng.standard_normal((n_y, n_y))
    )
    return g, spec, unwhiten


def _direct(g, spec, unwhiten, form, draws, seed=0) -> np.ndarray:
    """The fixed-point iteration written out on the residuals of each draw."""
    m, n_y, _ = g.shape
    rng = np.random.default_rng(seed)
    z = _weighting._complex_normal(rng, (draws, m, n_y))
    e = np.einsum("kab,dkb->dka", _weighting._spectral_roots(spec), z)
    fixed, free = [], []
    info = np.einsum("kap,kaq->pq", g.conj(), g).real
    for d in range(draws):
        theta = np.linalg.solve(info, np.einsum("kap,ka->p", g.conj(), e[d]).real)
        fixed.append(theta)
        for _ in range(200):
            r = e[d] - g @ theta
            s_u = r.T @ r.conj() / m
            s_v = unwhiten @ s_u @ unwhiten.conj().T
            if form == "sidpac":
                s_v = s_v.conj()
            elif form == "real":
                s_v = s_v.real
            w = unwhiten.conj().T @ np.linalg.inv(s_v) @ unwhiten
            a = np.einsum("kap,ab,kbq->pq", g.conj(), w, g).real
            b = np.einsum("kap,ab,kb->p", g.conj(), w, e[d]).real
            new = np.linalg.solve(a, b)
            if np.max(np.abs(new - theta)) < 1e-13 * np.max(np.abs(new)):
                theta = new
                break
            theta = new
        free.append(theta)
    return np.var(np.array(free), axis=0, ddof=1) / np.var(np.array(fixed), axis=0, ddof=1)


def test_the_frequency_spread_is_the_fixed_point_of_each_form() -> None:
    # Same draws, so the sums the spread expands must give the direct iteration's
    # estimates to rounding; the forms differ (the complex cross-spectrum and the
    # complex whitening tell them apart).
    g, spec, unwhiten = _frequency_problem()
    m_inv = np.linalg.inv(np.einsum("kap,kaq->pq", g.conj(), g).real)
    # the outputs in the order the spread draws them (`_canonical`): the same draws
    order = _weighting._canonical(np.einsum("kap,pq,kaq->a", g.conj(), m_inv, g).real)
    g, spec = g[:, order], spec[:, order][:, :, order]
    unwhiten = unwhiten[np.ix_(order, order)]
    real = np.zeros(g.shape[0], dtype=bool)
    seen = []
    for form in ("hermitian", "sidpac", "real"):
        got = _weighting.frequency_weighting_spread(
            g, spec, m_inv, real, form, unwhiten=unwhiten, draws=300, tol=0.0
        )
        np.testing.assert_allclose(got, _direct(g, spec, unwhiten, form, 300), rtol=1e-6)
        seen.append(got)
    assert np.max(np.abs(seen[0] - seen[1])) > 1e-3


def test_few_frequencies_with_a_noise_peak_widen_the_bars() -> None:
    # Twelve frequencies: the weighting rests on few degrees of freedom, and the
    # peaked output's weight moves with the noise that the fit takes up.
    g, spec, _ = _frequency_problem(m=12)
    m_inv = np.linalg.inv(np.einsum("kap,kaq->pq", g.conj(), g).real)
    real = np.zeros(12, dtype=bool)
    got = _weighting.frequency_weighting_spread(g, spec, m_inv, real, "hermitian", draws=2000)
    assert np.all(got > 1.05), got


def test_the_hermitian_weighting_does_not_see_the_whitening() -> None:
    # S^-1 of the outputs is L^-H S_u^-1 L^-1 whatever L is: the likelihood's
    # weighting is invariant, so the spread is the same with or without L.
    g, spec, unwhiten = _frequency_problem()
    m_inv = np.linalg.inv(np.einsum("kap,kaq->pq", g.conj(), g).real)
    real = np.zeros(g.shape[0], dtype=bool)
    with_l = _weighting.frequency_weighting_spread(
        g, spec, m_inv, real, "hermitian", unwhiten=unwhiten, draws=200
    )
    without = _weighting.frequency_weighting_spread(g, spec, m_inv, real, "hermitian", draws=200)
    np.testing.assert_allclose(with_l, without, rtol=1e-8)


def test_a_failed_inverse_or_spectrum_leaves_the_bars_alone() -> None:
    g = _design()
    nan = np.full((g.shape[2],) * 2, np.nan)
    assert np.all(_weighting.weighting_spread([g], [_spectrum(PHI)], nan, draws=10) == 1.0)
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    bad = _spectrum(PHI)
    bad[3, 0, 0] = np.nan
    assert np.all(_weighting.weighting_spread([g], [bad], m_inv, draws=10) == 1.0)


def test_the_draws_stop_once_every_ratio_is_known_to_two_per_cent() -> None:
    g = _design()
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    # white noise: the ratios are near one and tight after the first hundred draws
    white = _weighting.weighting_spread([g], [_spectrum(0.0)], m_inv)
    first = _weighting.weighting_spread(
        [g], [_spectrum(0.0)], m_inv, draws=_weighting._MIN_DRAWS, tol=0.0
    )
    np.testing.assert_array_equal(white, first)
    # slow noise: the slow derivatives' ratios need every draw
    slow = _weighting.weighting_spread([g], [_spectrum(PHI)], m_inv)
    full = _weighting.weighting_spread([g], [_spectrum(PHI)], m_inv, tol=0.0)
    np.testing.assert_array_equal(slow, full)


def test_the_ratios_standard_error_is_their_scatter_over_seeds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The stopping rule rests on the delta method's standard error of a ratio of
    # two mean squares over the same draws; over 20 seeds (400 draws each) it
    # matches the ratios' own scatter (whose relative error over 20 seeds is 16 %).
    g = _design()
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    spec = _spectrum(PHI)
    original = _weighting._ratio
    errors: list[np.ndarray] = []

    def keep(fixed: np.ndarray, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = original(fixed, free)
        errors.append(out[1])
        return out

    monkeypatch.setattr(_weighting, "_ratio", keep)
    ratios, final = [], []
    for seed in range(20):
        ratios.append(
            _weighting.weighting_spread([g], [spec], m_inv, draws=400, tol=0.0, seed=seed)
        )
        final.append(errors[-1])  # over all 400 draws (earlier batches are checked too)
    scatter = np.std(ratios, axis=0, ddof=1)
    ratio = np.mean(final, axis=0) / scatter
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_outputs_that_share_no_parameter_leave_the_bars_alone() -> None:
    # Each output's parameters are fitted by it alone: its weight scales their
    # information and moves no estimate, however slow its noise.
    g = _design()
    apart = g.copy()
    apart[:, 1, :3] = 0.0  # the derivatives on output 0 only, output 1 keeps its bias
    m_inv = np.linalg.inv(np.einsum("tap,taq->pq", apart, apart))
    ratio = _weighting.weighting_spread([apart], [_spectrum(PHI)], m_inv)
    np.testing.assert_array_equal(ratio, np.ones(apart.shape[2]))
    # the brute force agrees: the re-estimated weights change nothing
    np.testing.assert_allclose(_brute_force(apart, PHI, 200), 1.0, atol=1e-8)


def test_an_unknown_form_is_refused() -> None:
    g, spec, _ = _frequency_problem(m=12)
    m_inv = np.linalg.inv(np.einsum("kap,kaq->pq", g.conj(), g).real)
    with pytest.raises(ValueError, match="form"):
        _weighting.frequency_weighting_spread(g, spec, m_inv, np.zeros(12, bool), "diag")


@pytest.mark.parametrize("domain", ["time", "frequency"])
def test_bars_do_not_depend_on_the_order_of_the_outputs(domain):
    """The weighting spread's draws follow the outputs' own data, not their place, and
    the frequency-domain whitening is the Hermitian root: listing the outputs the
    other way round gives the same bars (before: up to 2 % apart, the Monte Carlo's
    own noise)."""
    import aeroid
    from aeroid.models import catalog

    p0 = {"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -6.0}
    model = catalog.short_period(p0)
    data = catalog.short_period_flight(seed=5, colored=0.9, duration=20.0)
    fit = aeroid.identify if domain == "time" else aeroid.identify_frequency_domain
    a = fit(model, data, list(p0), outputs=["alpha", "q"])
    b = fit(model, data, list(p0), outputs=["q", "alpha"])
    for k in p0:
        assert b.stderr[k] == pytest.approx(a.stderr[k], rel=1e-7)
        assert b.parameters[k] == pytest.approx(a.parameters[k], rel=1e-9)
