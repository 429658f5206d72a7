"""Benchmark: exact simulation of a linear model, blocked recursion vs a step-by-step loop.

``Model.simulate_batch`` of an affine model discretises it exactly and then
runs the recursion x_{k+1} = phi x_k + f_k. The library runs it in blocks of
about sqrt(T) samples (`aeroid.models.integration._linear_recursion`); the reference
here is the plain loop over samples it replaced. Reported: the ratio of the
medians per record length and batch size, the largest relative difference
between the two, and what it does to a whole identify and a short MCMC run.
Run: python tests/benchmarks/bench_simulate.py
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
import scipy.linalg
from _timing import median_time

import aeroid
from aeroid.models import catalog
from aeroid.models import integration as _integrate


def _step_by_step(phi: np.ndarray, x0: np.ndarray, forcing: np.ndarray) -> np.ndarray:
    out = np.empty_like(forcing)
    phi_t = np.ascontiguousarray(np.transpose(phi, (0, 2, 1)))
    x = x0
    for k in range(forcing.shape[1]):
        x = np.matmul(x[:, None, :], phi_t)[:, 0, :] + forcing[:, k]
        out[:, k] = x
    return out


def main() -> None:
    rng = np.random.default_rng(0)
    a = np.array([[-0.8, 1.0], [-4.0, -1.5]])
    print("recursion (2 states): samples x batch -> step-by-step / blocked, max rel. difference")
    for n_t in (500, 3000, 30000):
        for batch in (1, 6, 24):
            phi = np.stack([scipy.linalg.expm(a * 0.02 * (1 + 0.01 * b)) for b in range(batch)])
            forcing = 1e-3 * rng.normal(size=(batch, n_t, 2))
            x0 = rng.normal(size=(batch, 2))
            ref = _step_by_step(phi, x0, forcing)
            new = _integrate._linear_recursion(phi, x0, forcing)
            diff = float(np.max(np.abs(ref - new)) / np.max(np.abs(ref)))
            args = (phi, x0, forcing)
            t_ref = median_time(functools.partial(_step_by_step, *args), 5 if n_t > 5000 else 15)
            t_new = median_time(functools.partial(_integrate._linear_recursion, *args))
            print(
                f"  {n_t:6d} x {batch:2d}: {1e3 * t_ref:8.2f} ms / {1e3 * t_new:7.2f} ms"
                f" = {t_ref / t_new:5.1f}x   {diff:.1e}"
            )

    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    names = list(catalog.SHORT_PERIOD_TRUTH)
    fit = aeroid.identify(model, data, names)
    priors = {n: aeroid.Normal(v, abs(v)) for n, v in catalog.SHORT_PERIOD_TRUTH.items()}
    original = _integrate._linear_recursion
    for label, recursion in (("step-by-step", _step_by_step), ("blocked", original)):
        _integrate._linear_recursion = recursion  # type: ignore[assignment]
        try:
            t_fit = median_time(lambda: aeroid.identify(model, data, names), 9)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a short chain: unconverged on purpose
                t_mc = median_time(
                    lambda: aeroid.infer(
                        model, data, priors, initial=fit, n_walkers=12, n_steps=200, seed=1
                    ),
                    5,
                )
        finally:
            _integrate._linear_recursion = original
        print(
            f"{label:13s}: identify (10 s doublet) {1e3 * t_fit:6.1f} ms,"
            f" infer (12 walkers x 200 steps) {t_mc:5.2f} s"
        )


if __name__ == "__main__":
    main()
