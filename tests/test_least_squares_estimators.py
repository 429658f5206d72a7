"""Every iterative estimator runs through the one least-squares solver, and the
frequency-domain likelihood hands it the curvature of its concentrated cost."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import pytest

import aeroid
from aeroid.frequency._frequency_domain_fits import _concentrated, _stack
from aeroid.models import catalog


def _spy(monkeypatch: pytest.MonkeyPatch, module: Any, name: str) -> list[Any]:
    calls: list[Any] = []
    real = getattr(module, name)

    def counted(*args: Any, **kwargs: Any) -> Any:
        out = real(*args, **kwargs)
        calls.append(out)
        return out

    monkeypatch.setattr(module, name, counted)
    return calls


def _first_order_record() -> tuple[aeroid.Model, aeroid.FlightData]:
    # a model other than the short period: y' = (K u - y) / tau
    model = catalog.first_order()
    t = np.arange(0.0, 8.0, 0.02)
    u = catalog.doublet(t, start=1.0, width=1.0, amplitude=1.0)
    u = u + 0.5 * np.sin(2.1 * t)
    y = np.asarray(model.simulate(t, {"u": u}, {"y": 0.0}).outputs)[:, 0]
    y = y + 0.01 * np.random.default_rng(3).standard_normal(t.size)
    return model, aeroid.FlightData(time=t, channels={"y": y, "u": u})


def test_time_domain_estimators_call_the_one_solver(monkeypatch: pytest.MonkeyPatch) -> None:
    import aeroid.estimation._filter_error as fe
    import aeroid.estimation._output_error as oe

    oe_calls = _spy(monkeypatch, oe, "minimise")
    fe_calls = _spy(monkeypatch, fe, "minimise")
    model, data = _first_order_record()
    start = {k: 1.3 * v for k, v in model.parameters.items()}
    fit = aeroid.identify(model, data, start)
    assert len(oe_calls) == 1 and fit.n_iterations == oe_calls[0].iterations
    assert fit.parameters == pytest.approx(
        dict(zip(fit.parameter_names, oe_calls[0].theta, strict=False))
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        filt = aeroid.identify(model, data, start, method="filter_error", process_noise={"y": 1e-6})
    assert len(fe_calls) == 1 and filt.n_iterations == fe_calls[0].iterations
    # the two agree on this record, whose process noise is nil
    for n in fit.parameter_names:
        assert abs(filt.parameters[n] - fit.parameters[n]) < fit.stderr[n]


def test_frequency_domain_and_transfer_function_fits_call_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import aeroid.frequency._frequency_domain_fits as fdf
    import aeroid.frequency._rational_fit as rf

    fd_calls = _spy(monkeypatch, fdf, "minimise")
    tf_calls = _spy(monkeypatch, rf, "fit_residuals")
    model, data = _first_order_record()
    start = {k: 1.3 * v for k, v in model.parameters.items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fd = aeroid.identify_frequency_domain(model, data, start, boundary="estimate")
    assert fd_calls and fd.n_iterations == fd_calls[-1].iterations
    for fourier in (False, True):
        tf = aeroid.fit_transfer_function(
            data,
            input="u",
            output="y",
            numerator_order=0,
            denominator_order=1,
            delay=False,
            fourier=fourier,
        )
        assert len(tf_calls) >= 1 + fourier
    # Fourier output error (the last fit): b0 / (s + a0) with b0 = K / tau, a0 = 1 / tau
    K, tau = model.parameters["K"], model.parameters["tau"]
    assert abs(tf.parameters["b0"] - K / tau) < 4 * tf.stderr["b0"]
    assert abs(tf.parameters["a0"] - 1 / tau) < 4 * tf.stderr["a0"]


def test_concentrated_curvature_is_the_hessian_of_log_det() -> None:
    # residuals linear in theta, v = Z - A theta: the Gauss-Newton approximation is exact,
    # so the curvature must equal the Hessian of M/2 log det S by finite differences
    rng = np.random.default_rng(4)
    m, n_y, n = 60, 2, 3
    A = rng.standard_normal((m, n_y, n)) + 1j * rng.standard_normal((m, n_y, n))
    Z = rng.standard_normal((m, n_y)) + 1j * rng.standard_normal((m, n_y))

    def cost(th: np.ndarray, real: bool) -> float:
        v = Z - A @ th
        S = v.T @ v.conj() / m
        return 0.5 * m * float(np.linalg.slogdet(S.real if real else S)[1])

    theta = 0.1 * rng.standard_normal(n)
    for real in (False, True):
        v = Z - A @ theta
        S = v.T @ v.conj() / m
        if real:
            S = S.real.astype(np.complex128)
        Li = np.linalg.inv(np.linalg.cholesky(S))
        J = _stack(Li @ A).reshape(-1, n)
        curv = _concentrated(J.T @ J, v, A, real)
        h = 1e-4
        hess = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                ei, ej = np.eye(n)[i] * h, np.eye(n)[j] * h
                hess[i, j] = (
                    cost(theta + ei + ej, real)
                    - cost(theta + ei - ej, real)
                    - cost(theta - ei + ej, real)
                    + cost(theta - ei - ej, real)
                ) / (4 * h * h)
        np.testing.assert_allclose(curv, hess, rtol=1e-5, atol=1e-6 * np.max(np.abs(hess)))
        # and the gradient the solver is given is that of the same cost
        grad = -(J.T @ _stack(v @ Li.T).reshape(-1))
        num = [(cost(theta + e * h, real) - cost(theta - e * h, real)) / (2 * h) for e in np.eye(n)]
        np.testing.assert_allclose(grad, num, rtol=1e-6, atol=1e-8 * np.max(np.abs(num)))
