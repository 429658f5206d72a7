"""The suite's surrogate Monte Carlo against a known truth (tests/reference/check_mc.py).

On simulated records whose true sampling spread is exact, the Monte Carlo on a
record's own residuals reads a constant's and a bias's standard error low by
construction, while the library's default bars track the truth: the finding
behind the reference suite's separate summary of constants and biases.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

REF = pathlib.Path(__file__).resolve().parent / "reference"
sys.path.insert(0, str(REF))

import check_mc as C  # noqa: E402

SEEDS = 200


def _mean_and_se(ratio: np.ndarray) -> tuple[float, float]:
    """Mean over seeds of a variance ratio and its standard error."""
    return float(np.mean(ratio)), float(np.std(ratio, ddof=1) / np.sqrt(ratio.size))


def test_expected_mc_of_the_noise_itself_is_the_exact_variance() -> None:
    # Parseval: surrogates of white noise (no fit, H = 0) give each bin its expected
    # power, so the Monte Carlo's expectation is M^-1 G'G M^-1 up to the Nyquist bin
    # and bin 0's three-bin fill, negligible for smooth sensitivities
    case = C.EquationError(400, 0.0, 0)
    got = C.expected_mc_sd(case.design, 0.0, residuals=False)
    np.testing.assert_allclose(got, C.exact_sd(case.design, 0.0), rtol=2e-3)


def test_expected_mc_matches_the_exact_mc_of_one_design() -> None:
    # the closed form against the mean of linear_mc (the Monte Carlo with infinite
    # refits, exact for least squares) over seeded AR(1) records
    case = C.EquationError(300, 0.9, 0)
    m_inv = np.linalg.inv(case.design.T @ case.design)
    draws = []
    for seed in range(SEEDS):
        e = C.ar1(np.random.default_rng(seed), 300, 0.9)
        u = e - case.design @ (m_inv @ (case.design.T @ e))
        draws.append(C.S.linear_mc([case.design[:, None, :]], [u[:, None]], m_inv)[0])
    mean, se = np.mean(draws, axis=0), np.std(draws, axis=0, ddof=1) / np.sqrt(SEEDS)
    expected = C.expected_mc_sd(case.design, 0.9) ** 2
    assert np.all(np.abs(mean - expected) < 4.0 * se), (mean, expected, se)


def test_leverage_ratio_is_both_judges_exact_expectation_under_white_noise() -> None:
    # the Monte Carlo's against check_mc's closed form (a dense DFT), SIDPAC's colores
    # against the sandwich over the expected biased autocorrelation of (I - H) e,
    # summed sample by sample
    n = 240
    case = C.EquationError(n, 0.0, 0)
    x = case.design
    inv = np.linalg.inv(x.T @ x)
    mc = C.S.leverage_ratio([x[:, None, :]], inv)
    np.testing.assert_allclose(mc, C.expected_mc_sd(x, 0.0) / C.exact_sd(x, 0.0), rtol=1e-10)
    keep = np.eye(n) - x @ inv @ x.T
    acf = np.array([np.trace(keep, offset=k) / n for k in range(n)])
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    v = x @ inv
    dense = np.sqrt(np.diag(v.T @ acf[lags] @ v) / np.diag(v.T @ v))
    colores = C.S.leverage_ratio([x[:, None, :]], inv, padded=True)
    np.testing.assert_allclose(colores, dense, rtol=1e-10)
    # colores sums the residuals' autocorrelation, nothing at w = 0: a constant reads
    # about 0.6 of the truth even under white noise; the Monte Carlo's bin-0 fill
    # keeps it near the slopes'
    assert colores[-1] < 0.75 and mc[-1] > 0.85, (colores, mc)
    # two outputs with parameters of their own: each output's figures alone
    g = np.zeros((n, 2, 8))
    g[:, 0, :4] = x
    g[:, 1, 4:] = x[::-1]
    inv2 = np.linalg.inv(np.einsum("tap,taq->pq", g, g))
    both = C.S.leverage_ratio([g], inv2, padded=True)
    rev = np.linalg.inv(x[::-1].T @ x[::-1])
    alone = C.S.leverage_ratio([x[::-1, None, :]], rev, padded=True)
    np.testing.assert_allclose(both, np.concatenate([colores, alone]), rtol=1e-10)


def test_the_monte_carlo_reads_a_constant_low_and_our_bars_do_not() -> None:
    # equation error with a constant, AR(1) phi = 0.99 on 1000 samples (correlation
    # time 199 samples): over 200 seeds our default variance averages the exact one
    # (within 4 of its standard errors; its seed scatter is wide, few dof), the
    # surrogate Monte Carlo's is about half of it, as its closed form says
    case = C.EquationError(1000, 0.99, 0)
    rows = C.study(case, SEEDS)
    assert case.expected_mc is not None and case.exact is not None
    closed = case.expected_mc / case.exact
    const = rows[-1]
    assert const["parameter"] == "const"
    ours, ours_se = _mean_and_se(const["ours"] ** 2)
    assert abs(ours - 1.0) < 4.0 * ours_se, (ours, ours_se)
    mc, mc_se = _mean_and_se(const["lin"] ** 2)
    assert abs(mc - closed[-1] ** 2) < 4.0 * mc_se, (mc, closed[-1], mc_se)
    # the closed form: a constant's Monte Carlo 0.69 of the truth, the slopes' 0.90-0.92
    assert closed[-1] < 0.75 and np.all((closed[:-1] > 0.85) & (closed[:-1] < 0.95)), closed
    # so one record's ours / mc lands within 0.8-1.25 in well under half the seeds
    assert const["ours_mc_inside"] < 0.5, const["ours_mc_inside"]
    # SIDPAC's colores on the same records: a constant about half of the truth
    assert case.expected_sidpac is not None
    assert case.expected_sidpac[-1] / case.exact[-1] < 0.6


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["bias", "state"])
def test_output_error_biases_the_same(kind: str) -> None:
    # an output bias on a first-order lag and a bias on an integrator's state equation
    # (its sensitivity a ramp, as data compatibility's rate biases), fitted by
    # identify under AR(1) phi = 0.99 noise: our bars average the exact first-order
    # variance, the Monte Carlo's expectation is 0.79-0.83 of the truth
    case = C.OutputError(1000, 0.99, kind)
    rows = C.study(case, SEEDS)
    assert case.expected_mc is not None and case.exact is not None
    closed = case.expected_mc / case.exact
    bias = rows[-1]
    ours, ours_se = _mean_and_se(bias["ours"] ** 2)
    assert abs(ours - 1.0) < 4.0 * ours_se, (ours, ours_se)
    mc, mc_se = _mean_and_se(bias["lin"] ** 2)
    assert abs(mc - closed[-1] ** 2) < 4.0 * mc_se, (mc, closed[-1], mc_se)
    assert closed[-1] < 0.85, closed
    # the exact first-order variance is the seeds' own spread (200 seeds: the
    # variance to about 10 %; four of those)
    assert abs(bias["spread"] ** 2 / bias["true"] ** 2 - 1.0) < 0.4


def test_summary_counts_derivatives_and_constants_apart() -> None:
    def r(name: str, mc_ratio: float, sid_lev: float) -> dict[str, float | str | None]:
        out = C.S.row(
            "c",
            name,
            sidpac=1.0,
            sidpac_se_white=0.1,
            sidpac_se_corrected=0.2,
            ours=1.0,
            ours_se=0.3,
            mc_se=0.3 / mc_ratio,
        )
        out["sid_lev"] = sid_lev
        out["mc_lev"] = 0.9
        return out

    rows = [r("Cm_alpha", 1.0, 0.8), r("Cm_q", 1.5, 0.9), r("Cm_const", 1.6, 0.6)]
    s = C.S.summary(rows)
    assert s["target_mc_drv"] == "1/2" and s["target_mc_cb"] == "0/1"
    assert s["target_mc"] == "1/3"
    # ours over SIDPAC's corrected is 1.5; its leverage taken out, 1.5 * 0.8 and 1.5 * 0.9
    assert np.isclose(s["drv_lev_min"], 1.2) and np.isclose(s["drv_lev_max"], 1.35)
    assert s["target_se_lev"] == "1/2"
    assert np.isclose(s["cb_sidlev_min"], 0.6) and np.isclose(s["cb_mc_max"], 1.6)
