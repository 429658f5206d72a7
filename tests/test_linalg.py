"""The numpy matrix exponential, pinned to closed forms and to SciPy."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import scipy.linalg

from aeroid._linalg import expm


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 13])
def test_expm_equals_scipy_on_random_matrices(n):
    rng = np.random.default_rng(n)
    # the norms the discretisations meet (A h of a few units at most), batched
    for scale in (1e-9, 1e-3, 0.1, 0.5, 1.0):
        A = rng.standard_normal((6, n, n)) * scale / math.sqrt(n)
        E = expm(A)
        assert E.shape == A.shape
        for b in range(A.shape[0]):
            assert _rel(E[b], scipy.linalg.expm(A[b])) < 1e-13


@pytest.mark.parametrize("stiffness", [1e2, 1e4, 1e6])
def test_expm_equals_scipy_and_the_eigen_form_on_stiff_matrices(stiffness):
    rng = np.random.default_rng(7)
    n = 6
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    lam = -np.logspace(0, math.log10(stiffness), n)
    # the fastest mode over the step from 0.5 to 50 (exp's own condition number grows with
    # the norm, so past that no algorithm is accurate to 1e-13)
    for h in (0.5 / stiffness, 5.0 / stiffness, 50.0 / stiffness):
        A = (Q * lam) @ Q.T * h
        exact = (Q * np.exp(lam * h)) @ Q.T  # symmetric: expm(Q D Q') = Q e^D Q'
        E = expm(A)
        assert _rel(E, exact) < 1e-13
        assert _rel(E, scipy.linalg.expm(A)) < 1e-13


def test_expm_closed_forms():
    # rotation: exp([[0, -w], [w, 0]]) = [[cos w, -sin w], [sin w, cos w]], also for large w
    ws = (0.3, 4.0, 60.0, 1e-5)
    batch = expm(np.array([[[0.0, -w], [w, 0.0]] for w in ws]))  # members scaled differently
    for w, E in zip(ws, batch, strict=True):
        np.testing.assert_allclose(
            E, [[math.cos(w), -math.sin(w)], [math.sin(w), math.cos(w)]], rtol=0, atol=2e-13
        )
    # Jordan block: exp([[a, 1], [0, a]]) = e^a [[1, 1], [0, 1]]
    for a in (-30.0, -1.0, 2.0):
        E = expm(np.array([[a, 1.0], [0.0, a]]))
        np.testing.assert_allclose(E, math.exp(a) * np.array([[1.0, 1.0], [0.0, 1.0]]), rtol=1e-13)
    # nilpotent: exp(N) = I + N + N^2/2
    N = np.array([[0.0, 2.0, 3.0], [0.0, 0.0, 5.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(expm(N), np.eye(3) + N + N @ N / 2, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(
        expm(np.zeros((2, 3, 3))), np.broadcast_to(np.eye(3), (2, 3, 3)), rtol=1e-15, atol=0
    )


def test_expm_non_finite_member_is_nan_alone():
    A = np.zeros((3, 2, 2))
    A[0] = [[0.0, 1.0], [-1.0, 0.0]]
    A[1, 0, 0] = np.nan
    A[2] = [[-2.0, 0.0], [0.0, 1.0]]
    E = expm(A)
    assert np.all(np.isnan(E[1]))
    np.testing.assert_allclose(E[0], scipy.linalg.expm(A[0]), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(E[2], np.diag([math.exp(-2.0), math.e]), rtol=1e-14)
    with pytest.raises(ValueError, match="square"):
        expm(np.zeros((2, 3)))


@pytest.mark.parametrize("scale", [1e-6, 0.1, 3.0, 40.0])
def test_compiled_filters_expm_follows_the_numpy_one(scale):
    # the compiled EKF's exponential takes the numpy one's steps (Padé 13, the same
    # scaling): equal to rounding on small and large norms and non-normal matrices
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    from aeroid.estimation._ekf_compiled import _expm

    fn = jax.jit(_expm(jax, jax.numpy))
    rng = np.random.default_rng(11)
    A = rng.standard_normal((4, 4)) * scale / 2.0
    A[0, 3] += 50.0 * scale  # non-normal: the powers' norms, not ||A||, set the scaling
    E = np.asarray(fn(A))
    assert _rel(E, expm(A)) < 1e-12
    if scale <= 3.0:
        assert _rel(E, scipy.linalg.expm(A)) < 1e-12


def test_compiled_filters_expm_equals_the_closed_form():
    jax = pytest.importorskip("jax")
    jax.config.update("jax_enable_x64", True)
    from aeroid.estimation._ekf_compiled import _expm

    fn = jax.jit(_expm(jax, jax.numpy))
    # upper triangular, eigenvalues a and c: a norm that needs 6 squarings
    a, b, c = -3.0, 200.0, -0.5
    exact = np.array([[math.exp(a), b * (math.exp(a) - math.exp(c)) / (a - c)], [0.0, math.exp(c)]])
    assert _rel(np.asarray(fn(np.array([[a, b], [0.0, c]]))), exact) < 1e-13
    # a rotation
    w = 0.7
    R = np.asarray(fn(np.array([[0.0, -w], [w, 0.0]])))
    assert _rel(R, np.array([[math.cos(w), -math.sin(w)], [math.sin(w), math.cos(w)]])) < 1e-15


def test_information_inverse_sees_correlations_not_units() -> None:
    # a 2x2 information of parameters 1e-8 apart in size: the unscaled pseudo-inverse
    # cuts the small direction (condition 1e16 > 1/rcond); scaled it is the exact inverse
    from aeroid._linalg import information_inverse

    corr = np.array([[1.0, 0.3], [0.3, 1.0]])
    scale = np.array([1.0, 1e8])
    info = corr * np.outer(scale, scale)
    exact = np.linalg.inv(corr) / np.outer(scale, scale)
    np.testing.assert_allclose(information_inverse(info), exact, rtol=1e-12)
    assert np.linalg.pinv(info, rcond=1e-13, hermitian=True)[0, 0] < 0.5 * exact[0, 0]
    # an unknown with no information keeps a zero row and column
    blind = np.zeros((3, 3))
    blind[:2, :2] = info
    np.testing.assert_allclose(information_inverse(blind)[:2, :2], exact, rtol=1e-12)
    assert not np.any(information_inverse(blind)[2])


def _first_order() -> Any:
    """x' = a x + b u, every state measured."""
    import aeroid

    return aeroid.Model(
        ["x"],
        ["u"],
        {"a": -1.0, "b": 1.0},
        lambda t, x, u, p: np.array([p["a"] * x[0] + p["b"] * u[0]]),
    )


def test_identify_bars_follow_a_change_of_the_inputs_units() -> None:
    # the input written in units 1e8 times larger: the same fit, the gain's
    # estimate and bar 1e-8 of theirs, the pole's unchanged (its bar was 3e-17)
    import aeroid

    model = _first_order()
    t = np.arange(0.0, 10.0, 0.02)
    u = np.sin(1.3 * t) + np.sign(np.sin(0.4 * t))
    sim = model.simulate(t, {"u": u}, [0.0], {"a": -2.0, "b": 3.0}, method="exact")
    y = sim.states[:, 0] + 0.01 * np.random.default_rng(4).standard_normal(t.size)
    fits = []
    for k in (1.0, 1e8):
        data = aeroid.FlightData(t, {"x": y, "u": u * k})
        fits.append(aeroid.identify(model, data, {"a": -1.0, "b": 1.0 / k}, x0={"x": 0.0}))
    one, big = fits
    assert big.parameters["a"] == pytest.approx(one.parameters["a"], rel=1e-6)
    assert big.stderr["a"] == pytest.approx(one.stderr["a"], rel=1e-6)
    assert big.stderr["b"] * 1e8 == pytest.approx(one.stderr["b"], rel=1e-6)


def test_outputs_whose_squares_underflow_are_refused_not_fitted_at_the_start() -> None:
    # values near 1e-300 stalled LAPACK (or stopped "converged" at the start)
    import aeroid

    model = _first_order()
    t = np.arange(0.0, 5.0, 0.02)
    u = np.sin(1.3 * t)
    sim = model.simulate(t, {"u": u}, [0.0], {"a": -2.0, "b": 3e-300}, method="exact")
    data = aeroid.FlightData(t, {"x": sim.states[:, 0], "u": u})
    with pytest.raises(aeroid.IdentificationError, match=r"outputs \['x'\]: values below 1e-140"):
        aeroid.identify(model, data, {"a": -1.0, "b": 1e-300}, x0={"x": 0.0})
