"""Error bars and leave-one-out statistics of near-collinear sensitivities.

A sandwich is a covariance: under an invertible reparameterisation
``theta_a = A theta_b`` of the same fit it must map as ``A cov_b A'``. Formed
from ``M^-1``, the fit's projection loses ``eps cond(M)`` of every leverage
to cancellation (the bars of x1 and x1 + 1e-8 w read 0.005-0.35 of the
truth); over an orthonormal basis of the sensitivities
(`aeroid._linalg.information_basis`) they keep what the conditioning leaves.
"""

from __future__ import annotations

import numpy as np
import pytest

import aeroid
from aeroid import _colour
from aeroid._linalg import information_basis, information_inverse


def _ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    e = rng.standard_normal(n)
    out = np.empty(n)
    out[0] = e[0] / np.sqrt(1.0 - phi**2)
    for k in range(1, n):
        out[k] = phi * out[k - 1] + e[k]
    return out


def _pair(eps: float, seed: int = 0, n: int = 600) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regressors (1, x1, x1 + eps w), AR(1) 0.9 noise, and the well-conditioned
    equivalent (1, x1, w): ``X_a = X_b A^-1`` with ``A`` the map of their parameters."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.02
    x1 = np.sin(1.3 * t) + 0.5 * np.sin(3.1 * t + 0.4)
    w = np.sin(0.7 * t + 1.0) + 0.3 * rng.standard_normal(n)
    xa = np.column_stack([np.ones(n), x1, x1 + eps * w])
    xb = np.column_stack([np.ones(n), x1, w])
    z = 0.1 + x1 + 0.5 * w + 0.05 * _ar1(rng, n, 0.9)
    return xa, xb, z


@pytest.mark.parametrize("eps", [1e-4, 1e-6, 1e-7, 1e-8])
def test_kernel_maps_as_a_covariance(eps: float) -> None:
    xa, xb, z = _pair(eps)
    # theta_b = B theta_a: (c, t1 + t2, eps t2)
    b = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, eps]])
    a = np.linalg.inv(b)
    ta, *_ = np.linalg.lstsq(xa, z, rcond=None)
    u = (z - xa @ ta)[:, None]
    covs = []
    for x in (xa, xb):
        m_inv = information_inverse(x.T @ x, rcond=0.0)
        covs.append(_colour.colored_covariance([x[:, None, :]], [u], m_inv, rcond=0.0))
    (cov_a, nu_a), (cov_b, nu_b) = covs
    mapped = a @ cov_b @ a.T
    se_a, se_m = np.sqrt(np.diag(cov_a)), np.sqrt(np.diag(mapped))
    # the map's own rounding: the direction eps apart is known to eps_mach / eps
    np.testing.assert_allclose(se_a, se_m, rtol=max(1e-6, 1e-13 / eps))
    # the constant is a parameter of both: its degrees of freedom too
    assert nu_a[0] == pytest.approx(nu_b[0], rel=1e-4)


def test_equation_error_bars_under_collinearity() -> None:
    """The public estimator: near-collinear regressors get the bars the
    well-conditioned fit maps to (before: 0.6x at 1e-7, 19x at 1e-8)."""
    for eps in (1e-7, 1e-8):
        xa, xb, z = _pair(eps, seed=3)
        fa = aeroid.equation_error({"x1": xa[:, 1], "x2": xa[:, 2], "z": z}, "z", ["x1", "x2"])
        fb = aeroid.equation_error({"x1": xb[:, 1], "w": xb[:, 2], "z": z}, "z", ["x1", "w"])
        # x2's coefficient is w's over eps; x1's is x1's less it
        assert fa.stderr["x2"] == pytest.approx(fb.stderr["w"] / eps, rel=1e-4)
        assert fa.stderr["const"] == pytest.approx(fb.stderr["const"], rel=1e-4)


def test_basis_reproduces_the_pseudo_inverse() -> None:
    """``G M^+ = U T`` with U orthonormal, for a rank-deficient G and the cut
    `information_inverse` takes, over several records."""
    rng = np.random.default_rng(1)
    g1 = rng.standard_normal((50, 2, 4))
    g1[:, :, 3] = g1[:, :, 0] - 2.0 * g1[:, :, 1]  # a direction no data see
    g1[:, :, 2] *= 1e4  # a parameter in other units
    g2 = rng.standard_normal((30, 2, 4))
    g2[:, :, 3] = g2[:, :, 0] - 2.0 * g2[:, :, 1]
    g2[:, :, 2] *= 1e4
    info = sum(np.einsum("tap,taq->pq", g, g) for g in (g1, g2))
    m_inv = information_inverse(info, rcond=1e-13)
    spans, to_params = information_basis([g1, g2], 1e-13)
    assert to_params.shape == (3, 4)
    stacked = np.concatenate([s.reshape(-1, 3) for s in spans])
    np.testing.assert_allclose(stacked.T @ stacked, np.eye(3), atol=1e-12)
    for g, s in zip((g1, g2), spans, strict=True):
        np.testing.assert_allclose(
            s.reshape(-1, 3) @ to_params, g.reshape(-1, 4) @ m_inv, atol=1e-10 * np.abs(m_inv).max()
        )


def test_press_under_collinearity() -> None:
    """PRESS depends on the column space alone: the same for both bases (the hat
    matrix from ``(X'X)^-1`` had a trace of 1.97 for 3 columns at 1e-8)."""
    for eps in (1e-6, 1e-8):
        xa, xb, z = _pair(eps, seed=3)
        fa = aeroid.equation_error({"x1": xa[:, 1], "x2": xa[:, 2], "z": z}, "z", ["x1", "x2"])
        fb = aeroid.equation_error({"x1": xb[:, 1], "w": xb[:, 2], "z": z}, "z", ["x1", "w"])
        assert fa.press == pytest.approx(fb.press, rel=1e-7)


def test_frequency_domain_bars_under_collinearity() -> None:
    """`frequency_sandwich`, through the frequency-domain equation error."""
    freq = np.arange(0.05, 1.5, 0.02)
    for eps in (1e-7, 1e-8):
        xa, xb, z = _pair(eps, seed=5, n=2000)
        kw = {"domain": "frequency", "frequencies": freq, "dt": 0.02}
        fa = aeroid.equation_error(
            {"x1": xa[:, 1], "x2": xa[:, 2], "z": z}, "z", ["x1", "x2"], **kw
        )
        fb = aeroid.equation_error({"x1": xb[:, 1], "w": xb[:, 2], "z": z}, "z", ["x1", "w"], **kw)
        assert fa.stderr["x2"] == pytest.approx(fb.stderr["w"] / eps, rel=1e-5)
        assert fa.stderr["x1"] == pytest.approx(fb.stderr["w"] / eps, rel=1e-5)


def test_stepwise_names_the_candidates_it_never_weighed() -> None:
    """A candidate within 1 part in 1e8 of the model's span (variance inflation above
    1e8) is skipped, its partial F being rounding: it is named, not dropped in
    silence; one 1e-3 apart is weighed and enters."""
    import warnings

    xa, _, z = _pair(1e-4, seed=2)
    data = {"x1": xa[:, 1], "x2": xa[:, 2], "z": z}
    with pytest.warns(aeroid.IdentifiabilityWarning, match=r"\['x[12]'\] never weighed"):
        res = aeroid.stepwise_regression(data, "z", ["x1", "x2"])
    assert len(res.selected) == 1
    xa, _, z = _pair(1e-2, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", aeroid.IdentifiabilityWarning)
        res = aeroid.stepwise_regression(
            {"x1": xa[:, 1], "x2": xa[:, 2], "z": z}, "z", ["x1", "x2"]
        )
    assert set(res.selected) == {"x1", "x2"}
