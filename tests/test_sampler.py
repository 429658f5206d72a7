"""Ensemble sampler and diagnostics: Gaussian target moments, AR(1) autocorrelation times,
R-hat, rejection of invalid proposals, seeding and exact resumption."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeroid import (
    ChainState,
    InferenceError,
    autocorrelation_time,
    effective_sample_size,
    ensemble_sampler,
    split_r_hat,
)

MU = np.array([1.0, -2.0])
COV = np.array([[1.0, 1.6], [1.6, 4.0]])  # correlation 0.8
PREC = np.linalg.inv(COV)


def gauss(theta: np.ndarray) -> np.ndarray:
    d = theta - MU
    return -0.5 * np.einsum("bi,ij,bj->b", d, PREC, d)


def ar1(phi: float, n: int, m: int, seed: int) -> np.ndarray:
    """m independent stationary AR(1) chains of length n (unit innovation variance)."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((n, m))
    x = np.empty((n, m))
    x[0] = e[0] / math.sqrt(1.0 - phi**2)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


@pytest.mark.parametrize("move", ["stretch", "de"])
def test_correlated_gaussian_moments(move: str) -> None:
    start = MU + 0.1 * np.random.default_rng(1).standard_normal((32, 2))
    run = ensemble_sampler(gauss, start, 3000, seed=0, burn_in=500, move=move)
    assert run.move == move
    s = run.chain.reshape(-1, 2)
    # ESS is ~2000 here, so moment errors are ~2-5 %; the spec's tolerance is rel 0.15
    np.testing.assert_allclose(s.mean(axis=0), MU, rtol=0.15)
    np.testing.assert_allclose(np.cov(s.T), COV, rtol=0.15)
    assert 0.3 < run.acceptance_fraction.mean() < 0.9
    assert run.chain.shape == (2500, 32, 2)
    assert run.log_prob.shape == (2500, 32)
    np.testing.assert_allclose(run.log_prob, gauss(s).reshape(2500, 32))


@pytest.mark.parametrize("phi", [0.5, 0.9])
def test_autocorrelation_time_of_ar1(phi: float) -> None:
    # 32 chains x 4000 steps: the Sokal estimator's relative sd is about
    # sqrt(2 (2M + 1) / N) with M ~ 5 tau, N = 128,000 draws: < 5 %, against rel 0.2
    x = ar1(phi, 4000, 32, seed=int(phi * 10))
    tau = (1 + phi) / (1 - phi)
    assert autocorrelation_time(x) == pytest.approx(tau, rel=0.2)
    ess = effective_sample_size(x)
    assert ess == pytest.approx(x.size / autocorrelation_time(x), rel=1e-12)
    # the (n_steps, n_chains, n_dim) form returns one value per dimension
    both = np.stack([x, ar1(0.0, 4000, 32, seed=3)], axis=2)
    taus = autocorrelation_time(both)
    assert taus.shape == (2,)
    assert taus[0] == pytest.approx(tau, rel=0.2)
    assert taus[1] == pytest.approx(1.0, rel=0.2)


def test_autocorrelation_time_single_chain_and_constant() -> None:
    x = ar1(0.8, 40_000, 1, seed=5)[:, 0]
    assert autocorrelation_time(x) == pytest.approx(9.0, rel=0.2)
    assert autocorrelation_time(np.ones((50, 4))) == math.inf
    assert effective_sample_size(np.ones((50, 4))) == 0.0


def test_split_r_hat() -> None:
    rng = np.random.default_rng(2)
    same = rng.standard_normal((2000, 8))
    # iid chains: R-hat - 1 is O(1/n)
    assert split_r_hat(same) == pytest.approx(1.0, abs=0.005)
    shifted = same + np.arange(8)[None, :]
    assert split_r_hat(shifted) > 1.5
    # a trend within chains is caught by the split
    trend = same + np.linspace(0.0, 5.0, 2000)[:, None]
    assert split_r_hat(trend) > 1.2
    per_dim = split_r_hat(np.stack([same, shifted], axis=2))
    assert per_dim.shape == (2,)
    assert per_dim[0] < 1.01 < per_dim[1]
    # closed form for two constant halves: W = 0, so R-hat is infinite
    assert split_r_hat(np.repeat([[0.0], [1.0]], 4, axis=0)) == math.inf


def test_invalid_log_prob_is_rejection_never_a_crash() -> None:
    # half-plane support; NaN and +inf outside count as rejections
    def lp(theta: np.ndarray) -> np.ndarray:
        out = gauss(theta)
        out[theta[:, 0] < 0.5] = np.nan
        out[theta[:, 0] > 3.0] = np.inf
        return out

    start = MU + 0.05 * np.random.default_rng(3).standard_normal((16, 2))
    run = ensemble_sampler(lp, start, 400, seed=1)
    s = run.chain.reshape(-1, 2)
    assert np.all(np.isfinite(s))
    assert np.all((s[:, 0] >= 0.5) & (s[:, 0] <= 3.0))
    assert np.all(np.isfinite(run.log_prob))


def test_start_with_some_impossible_walkers_recovers() -> None:
    def lp(theta: np.ndarray) -> np.ndarray:
        return np.where(theta[:, 0] > 0, gauss(theta), -np.inf)

    start = MU + 0.1 * np.random.default_rng(4).standard_normal((16, 2))
    start[:3, 0] = -1.0  # three walkers start where the density is zero
    run = ensemble_sampler(lp, start, 300, seed=2)
    assert np.all(np.isfinite(run.state.log_prob))


@pytest.mark.parametrize("move", ["stretch", "de", "demcz"])
def test_seeded_and_resumable(move: str) -> None:
    start = MU + 0.1 * np.random.default_rng(5).standard_normal((8, 2))
    a = ensemble_sampler(gauss, start, 120, seed=11, burn_in=20, move=move)
    b = ensemble_sampler(gauss, start, 120, seed=11, burn_in=20, move=move)
    np.testing.assert_array_equal(a.chain, b.chain)
    c = ensemble_sampler(gauss, start, 120, seed=12, burn_in=20, move=move)
    assert not np.array_equal(a.chain, c.chain)
    # 50 + 70 steps from the stored state = one run of 120 steps, bit for bit
    first = ensemble_sampler(gauss, start, 50, seed=11, burn_in=20, move=move)
    st = first.state
    stored = ChainState(
        np.array(st.positions),
        np.array(st.log_prob),
        st.step,
        st.entropy,
        list(st.spawn_key),
        np.array(st.archive),
    )
    second = ensemble_sampler(gauss, stored, 70, move=move)
    np.testing.assert_array_equal(np.concatenate([first.chain, second.chain]), a.chain)
    np.testing.assert_array_equal(second.state.positions, a.state.positions)
    assert second.state.step == 120
    # a seed given with a state starts a fresh stream from that state
    fresh = ensemble_sampler(gauss, stored, 70, seed=99, move=move)
    assert not np.array_equal(fresh.chain, second.chain)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_differential_evolution_mixes_faster_on_a_correlated_gaussian(seed: int) -> None:
    # six correlated parameters with scales over four decades: the case of aerodynamic
    # derivatives and noise levels. Both moves are affine invariant; DE's autocorrelation
    # time is several times shorter (3.1-5.1x over eight seeds; asserted > 2x).
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    scale = np.diag(np.logspace(-3, 1, 6))
    cov = scale @ q @ np.diag([1.0, 0.5, 0.2, 0.1, 0.05, 0.02]) @ q.T @ scale
    prec = np.linalg.inv(cov)

    def lp(theta: np.ndarray) -> np.ndarray:
        return -0.5 * np.einsum("bi,ij,bj->b", theta, prec, theta)

    start = rng.multivariate_normal(np.zeros(6), cov, size=16)
    taus = {}
    for move in ("stretch", "de"):
        run = ensemble_sampler(lp, start, 4000, seed=seed, burn_in=1000, move=move)
        taus[move] = float(np.max(autocorrelation_time(run.chain)))
        s = run.chain.reshape(-1, 6)
        # both sample the target: variances within 25 % (ESS >= ~1000 for either move)
        np.testing.assert_allclose(np.var(s, axis=0), np.diag(cov), rtol=0.25)
    assert taus["de"] < taus["stretch"] / 2


def _target(d: int) -> tuple[np.ndarray, np.ndarray]:
    """A correlated Gaussian with scales over four decades (derivatives and noise levels)."""
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    scale = np.diag(np.logspace(-3, 1, d))
    cov = scale @ q @ np.diag(np.logspace(0, -1.7, d)) @ q.T @ scale
    return np.linspace(-1.0, 1.0, d) @ scale, cov


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_demcz_gaussian_moments_within_their_errors(seed: int) -> None:
    mu, cov = _target(4)
    prec = np.linalg.inv(cov)
    chol = np.linalg.cholesky(cov)

    def lp(theta: np.ndarray) -> np.ndarray:
        d = theta - mu
        return -0.5 * np.einsum("bi,ij,bj->b", d, prec, d)

    # started as `infer` starts: a ball of half the covariance, one sd off the mean
    rng = np.random.default_rng(seed + 100)
    start = mu + (chol @ (1.0 + 0.5 * rng.standard_normal((8, 4))).T).T
    run = ensemble_sampler(lp, start, 3000, seed=seed, burn_in=300, move="demcz")
    assert run.move == "demcz"
    s = run.chain.reshape(-1, 4)
    ess = effective_sample_size(run.chain)
    assert np.all(ess > 500)
    sd = np.sqrt(np.diag(cov))
    # the mean's standard error is sd / sqrt(ESS): within 4 of them
    assert np.all(np.abs(s.mean(axis=0) - mu) < 4.0 * sd / np.sqrt(ess))
    # a variance estimate's relative standard error is about sqrt(2 / ESS): within 4
    np.testing.assert_array_less(np.abs(np.var(s, axis=0) / sd**2 - 1.0), 4.0 * np.sqrt(2.0 / ess))
    # correlations, through the whitened draws' covariance: the identity to ~sqrt(2 / ESS)
    white = np.linalg.solve(chol, (s - mu).T)
    off = np.cov(white)[~np.eye(4, dtype=bool)]
    assert np.all(np.abs(off) < 4.0 * np.sqrt(2.0 / ess.min()))
    assert 0.15 < run.acceptance_fraction.mean() < 0.6
    np.testing.assert_allclose(run.log_prob, lp(s).reshape(run.log_prob.shape))


def test_demcz_keeps_the_target_invariant() -> None:
    # an archive of target draws and 4000 walkers started at target draws: after 30
    # steps every walker is still a target draw (each step is a Metropolis step given the
    # archive, which gains only target draws). The 90 % interval of each coordinate then
    # holds a Binomial(4000, 0.9) count of walkers (sd 19; within 4 sd), and the means
    # stay within 4 standard errors; a move that broke detailed balance drifts out
    mu, cov = MU, COV
    rng = np.random.default_rng(8)
    walkers = rng.multivariate_normal(mu, cov, size=4000)
    archive = rng.multivariate_normal(mu, cov, size=500)
    state = ChainState(walkers, gauss(walkers), 0, 5, (), archive)
    run = ensemble_sampler(gauss, state, 30, move="demcz")
    x = run.state.positions
    # no burn-in: nothing dropped, the walkers' positions appended
    np.testing.assert_array_equal(run.state.archive[:500], archive)
    assert run.state.archive.shape[0] > 500 + 4000
    sd = np.sqrt(np.diag(cov))
    inside = np.sum(np.abs(x - mu) < 1.6449 * sd, axis=0)
    assert np.all(np.abs(inside - 3600) < 4 * math.sqrt(4000 * 0.9 * 0.1))
    assert np.all(np.abs(x.mean(axis=0) - mu) < 4 * sd / math.sqrt(4000))
    assert run.acceptance_fraction.mean() > 0.2


def test_chain_state_archive_shape_is_checked() -> None:
    with pytest.raises(InferenceError, match=r"archive of shape \(5, 3\) for 2 parameters"):
        ChainState(np.zeros((4, 2)), np.zeros(4), 0, 1, (), np.zeros((5, 3)))
    assert ChainState(np.zeros((4, 2)), np.zeros(4), 0, 1, ()).archive.shape == (0, 2)


def test_demcz_archive_drops_the_burn_ins_first_half() -> None:
    start = MU + 0.1 * np.random.default_rng(9).standard_normal((8, 2))
    short = ensemble_sampler(gauss, start, 60, seed=4, burn_in=40, move="demcz")
    long = ensemble_sampler(gauss, start, 200, seed=4, burn_in=40, move="demcz")
    # the start and the first 20 burn-in steps dropped: steps 20-59 of 8 walkers kept
    assert short.state.archive.shape == (40 * 8, 2)
    np.testing.assert_array_equal(short.state.archive[-8:], short.state.positions)
    assert long.state.archive.shape == (180 * 8, 2)
    np.testing.assert_array_equal(long.state.archive[:320], short.state.archive)
    np.testing.assert_array_equal(short.chain, long.chain[:20])
    # the other moves keep no archive
    de = ensemble_sampler(gauss, start, 60, seed=4, burn_in=40, move="de")
    assert de.state.archive.shape == (0, 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_demcz_mixes_per_call_faster_than_two_halves(seed: int) -> None:
    # the case of `infer`'s default walkers (2 n_dim + 2 or more) on four parameters: per
    # call of log_prob (the costly batched simulation) DE-MCz's autocorrelation time is
    # 2.4-3.7x shorter than DE's (one call a step against two; 13-16 steps against
    # 18-27 here over six seeds); asserted > 1.6x
    mu, cov = _target(4)
    prec = np.linalg.inv(cov)

    def lp(theta: np.ndarray) -> np.ndarray:
        d = theta - mu
        return -0.5 * np.einsum("bi,ij,bj->b", d, prec, d)

    start = np.random.default_rng(seed).multivariate_normal(mu, 0.25 * cov, size=8)
    per_call = {}
    for move, calls_per_step in (("de", 2), ("demcz", 1)):
        run = ensemble_sampler(lp, start, 3000, seed=seed, burn_in=300, move=move)
        per_call[move] = calls_per_step * float(np.max(autocorrelation_time(run.chain)))
    assert per_call["demcz"] < per_call["de"] / 1.6


def test_thinning_and_burn_in() -> None:
    start = MU + 0.1 * np.random.default_rng(6).standard_normal((8, 2))
    full = ensemble_sampler(gauss, start, 100, seed=3)
    thinned = ensemble_sampler(gauss, start, 100, seed=3, burn_in=10, thin=7)
    assert thinned.chain.shape[0] == (100 - 10) // 7
    np.testing.assert_array_equal(thinned.chain, full.chain[10 + 6 :: 7][: thinned.chain.shape[0]])
    assert thinned.accepted.sum() == full.accepted.sum()


def test_one_vectorised_call_per_half_ensemble() -> None:
    calls: list[int] = []

    def lp(theta: np.ndarray) -> np.ndarray:
        calls.append(theta.shape[0])
        return gauss(theta)

    start = MU + 0.1 * np.random.default_rng(7).standard_normal((12, 2))
    ensemble_sampler(lp, start, 25, seed=0)
    assert calls == [6] * (2 + 2 * 25)
    calls.clear()
    # DE-MCz: the whole ensemble in one call, at the start and at every step
    ensemble_sampler(lp, start, 25, seed=0, move="demcz")
    assert calls == [12] * (1 + 25)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_steps": 0}, "n_steps"),
        ({"n_steps": 10, "burn_in": 10}, "burn_in"),
        ({"n_steps": 10, "thin": 0}, "thin"),
        ({"n_steps": 10, "stretch": 1.0}, "stretch"),
        ({"n_steps": 10, "stretch": "2"}, "stretch: expected a number > 1, got '2'"),
        ({"n_steps": 10, "stretch": True}, "stretch: expected a number > 1, got True"),
        ({"n_steps": 10, "move": "walk"}, "move"),
        ({"n_steps": 10, "seed": -1}, "seed"),
    ],
)
def test_bad_arguments(kwargs: dict, match: str) -> None:
    start = MU + 0.1 * np.random.default_rng(8).standard_normal((8, 2))
    with pytest.raises(InferenceError, match=match):
        ensemble_sampler(gauss, start, **kwargs)


def test_bad_ensembles_and_log_prob() -> None:
    with pytest.raises(InferenceError, match="n_walkers"):
        ensemble_sampler(gauss, np.zeros((3, 2)), 10)  # too few and odd
    with pytest.raises(InferenceError, match="n_walkers"):
        ensemble_sampler(gauss, np.zeros((7, 2)), 10)
    with pytest.raises(InferenceError, match="shape"):
        ensemble_sampler(gauss, np.zeros(8), 10)
    spread = np.random.default_rng(0).standard_normal((8, 2))
    with pytest.raises(InferenceError, match="finite log-probability"):
        ensemble_sampler(lambda t: np.full(t.shape[0], -np.inf), spread, 10)
    with pytest.raises(InferenceError, match="log_prob returned shape"):
        ensemble_sampler(lambda t: np.zeros((t.shape[0], 2)), spread, 10)
    with pytest.raises(InferenceError, match="shape"):
        autocorrelation_time(np.zeros((2, 2, 2, 2)))
    with pytest.raises(InferenceError, match="NaN"):
        split_r_hat(np.full((10, 2), np.nan))


@pytest.mark.parametrize("c", ["x", -1.0, 0.0, math.nan, None])
def test_window_constant_is_named(c: object) -> None:
    chains = np.random.default_rng(0).standard_normal((200, 2))
    for diagnostic in (autocorrelation_time, effective_sample_size):
        with pytest.raises(InferenceError, match="c: expected a positive window constant"):
            diagnostic(chains, c=c)


def test_a_log_prob_that_raises_or_returns_text_is_named() -> None:
    start = np.random.default_rng(0).standard_normal((8, 2))

    def boom(theta: np.ndarray) -> np.ndarray:
        raise ValueError("boom")

    with pytest.raises(InferenceError, match=r"log_prob raised ValueError on a batch of 4 .*boom"):
        ensemble_sampler(boom, start, 10, seed=1)
    with pytest.raises(InferenceError, match=r"log_prob raised ValueError"):
        ensemble_sampler(lambda theta: ["x"] * len(theta), start, 10, seed=1)


@pytest.mark.parametrize("move", ["stretch", "de", "demcz"])
def test_a_start_without_spread_in_a_direction_is_refused(move: str) -> None:
    # the moves only move along differences of walkers: a coordinate where every walker
    # starts alike would keep sd 0 for ever (it did, at acceptance 0.56-0.74)
    start = np.random.default_rng(0).standard_normal((8, 2))
    start[:, 1] = 0.5
    with pytest.raises(InferenceError, match=r"no spread in coordinate\(s\) \[1\]"):
        ensemble_sampler(gauss, start, 50, seed=0, move=move)
    with pytest.raises(InferenceError, match=r"no spread in coordinate\(s\) \[0, 1\]"):
        ensemble_sampler(gauss, np.ones((8, 2)), 50, seed=0, move=move)
    # walkers on a line through the plane span one direction only
    line = np.random.default_rng(1).standard_normal((8, 1)) * np.array([[1.0, -2.0]])
    with pytest.raises(InferenceError, match=r"coordinates \[0, 1\] .* linearly dependent"):
        ensemble_sampler(gauss, line + MU, 50, seed=0, move=move)
    stored = ChainState(start, gauss(start), 0, 1, ())
    with pytest.raises(InferenceError, match="no spread"):
        ensemble_sampler(gauss, stored, 50, move=move)


@pytest.mark.parametrize("move", ["stretch", "de", "demcz"])
def test_continuing_a_state_with_another_log_prob_rescores_it(move: str) -> None:
    # the same density normalised differently: the stored values belong to the old
    # function, and kept, no proposal was ever accepted (acceptance 0 over 200 steps)
    start = MU + 0.1 * np.random.default_rng(9).standard_normal((16, 2))
    first = ensemble_sampler(gauss, start, 100, seed=1, move=move)

    def shifted(theta: np.ndarray) -> np.ndarray:
        return gauss(theta) - 1000.0

    second = ensemble_sampler(shifted, first.state, 200, move=move)
    np.testing.assert_allclose(
        second.log_prob, shifted(second.chain.reshape(-1, 2)).reshape(200, 16)
    )
    assert second.acceptance_fraction.mean() > 0.2
    # the walkers' moves compare differences of log-probabilities: a constant shift
    # leaves the trajectories as they were
    same = ensemble_sampler(gauss, first.state, 200, move=move)
    np.testing.assert_allclose(second.chain, same.chain, rtol=0, atol=1e-9)
