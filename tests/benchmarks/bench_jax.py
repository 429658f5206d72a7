"""Benchmark of the JAX backend on the short-period truth case (run as a script).

    python tests/benchmarks/bench_jax.py

Times (medians over repeats, after compilation):
* the compiled RK4 rollout vs the numpy RK4 and the adaptive RK45 of `Model.simulate`;
* the exact Jacobian (jax.jacfwd) vs a central finite-difference Jacobian from one
  `simulate_batch` call;
* `identify(gradient="jax")` vs `identify()` (finite differences); target: jax at
  least as fast (ratio FD / jax >= 1).
"""

from __future__ import annotations

import time
from typing import Any

import jax.numpy as jnp
import numpy as np
from _timing import median_time

import aeroid
from aeroid.models import catalog
from aeroid.models import jax_compiled as _jax

NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]


def _sp_jax(t: Any, x: Any, u: Any, p: Any) -> Any:
    alpha, q = x[0], x[1]
    return jnp.array(
        [
            p["Z_alpha"] * alpha + q,
            p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0],
        ]
    )


def jax_model() -> aeroid.Model:
    return aeroid.Model(
        ["alpha", "q"], ["elevator"], dict(catalog.SHORT_PERIOD_GUESS), _sp_jax, name="sp_jax"
    )


def row(label: str, seconds: float, jax_seconds: float | None = None) -> None:
    """One timing line; the ratio is this time over the JAX time (> 1: JAX is faster)."""
    ratio = f"   ratio {seconds / jax_seconds:6.2f}x" if jax_seconds is not None else ""
    print(f"  {label:<48s} {seconds * 1e3:9.3f} ms{ratio}")


def main() -> None:
    data = catalog.short_period_flight(seed=0)
    t, u = data.time, data.array(["elevator"])
    truth = dict(catalog.SHORT_PERIOD_TRUTH)
    mj = jax_model()
    mn = catalog.short_period()

    print("Rollout, 501 samples (truth parameters)")
    t0 = time.perf_counter()
    aeroid.simulate_rk4(mj, t, u, [0.0, 0.0], truth, substeps=4)
    print(f"  first call incl. compilation: {time.perf_counter() - t0:.3f} s")
    jax_t = median_time(lambda: aeroid.simulate_rk4(mj, t, u, [0.0, 0.0], truth, substeps=4))
    rk4_t = median_time(lambda: mn.simulate(t, u, [0.0, 0.0], truth, method="rk4", substeps=4))
    rk45_t = median_time(lambda: mn.simulate(t, u, [0.0, 0.0], truth), repeats=3)
    row("simulate_rk4 (jax, substeps=4)", jax_t)
    row("Model.simulate rk4 (numpy, substeps=4)", rk4_t, jax_t)
    row("Model.simulate RK45 (solve_ivp)", rk45_t, jax_t)
    print("  (ratio = numpy time / jax time)")

    print("Jacobian, 4 parameters")
    x0 = np.zeros(2)
    _jax.outputs_and_jacobian(mj, t, u, x0, truth, NAMES, substeps=2)
    jac_t = median_time(lambda: _jax.outputs_and_jacobian(mj, t, u, x0, truth, NAMES, substeps=2))

    def fd() -> None:
        cols: dict[str, Any] = {k: np.full(2 * len(NAMES) + 1, v) for k, v in truth.items()}
        for j, n in enumerate(NAMES):
            h = 1e-6 * abs(truth[n])
            cols[n][2 * j] += h
            cols[n][2 * j + 1] -= h
        mn.simulate_batch(t, u, x0, cols, method="auto")

    fd_t = median_time(fd)
    row("jax.jacfwd through the RK4 rollout", jac_t)
    row("central differences, one simulate_batch (auto)", fd_t, jac_t)

    identify = getattr(aeroid, "identify", None)
    if identify is None:
        print("identify: not available yet (aeroid.identify missing); skipped")
        return
    print("identify on the noisy truth case, 4 parameters")
    identify(mj, data, NAMES, gradient="jax")  # compile
    jax_id = median_time(lambda: identify(mj, data, NAMES, gradient="jax"), repeats=5)
    fd_np = median_time(lambda: identify(mn, data, NAMES), repeats=5)
    fd_jm = median_time(lambda: identify(mj, data, NAMES), repeats=3)
    row('identify(gradient="jax")', jax_id)
    row("identify() finite differences, numpy dynamics", fd_np, jax_id)
    row("identify() finite differences, jax.numpy dynamics", fd_jm, jax_id)
    print("  target: ratio (FD / jax) >= 1")
    rj = identify(mj, data, NAMES, gradient="jax").parameters
    rf = identify(mn, data, NAMES).parameters
    worst = max(abs(rj[n] - rf[n]) / abs(rf[n]) for n in NAMES)
    print(f"  largest relative difference of the estimates: {worst:.2e}")


if __name__ == "__main__":
    main()
