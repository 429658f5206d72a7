"""Benchmark: likelihood evaluations per second in `aeroid.infer`.

Problem (the issue's): the short-period truth case windowed to 4 s (201
samples), 16 walkers, noise given, walkers started at the least-squares fit.
Reported figure: n_walkers * n_steps / wall time, median of several runs,
against the target of 1,000 evaluations/s (the competitor manages ~38/s).

    python tests/benchmarks/bench_infer.py [--steps 500] [--repeats 5] [--jax]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from typing import Any

import numpy as np

import aeroid
from aeroid.models import catalog

TARGET = 1000.0
COMPETITOR = 38.0
NOISE = {"alpha": 0.005, "q": 0.01}
PRIORS = {
    "Z_alpha": aeroid.Normal(-1.0, 1.0),
    "M_alpha": aeroid.Normal(-4.0, 4.0),
    "M_q": aeroid.Normal(-2.0, 2.0),
    "M_delta": aeroid.Normal(-6.0, 6.0),
}


def least_squares_fit(model: aeroid.Model, data: aeroid.FlightData) -> Any:
    """`aeroid.identify` when available, else a plain scipy fit (same starting point)."""
    identify = getattr(aeroid, "identify", None)
    if identify is not None:
        return identify(model, data, list(PRIORS))
    import scipy.optimize

    names = list(PRIORS)
    y = data.array(["alpha", "q"])
    w = np.array([NOISE["alpha"], NOISE["q"]])

    def residuals(theta: np.ndarray) -> np.ndarray:
        sim = model.simulate_data(
            data, parameters=dict(zip(names, theta, strict=True)), method="auto"
        )
        return ((sim.outputs - y) / w).ravel()

    x0 = [catalog.SHORT_PERIOD_GUESS[n] for n in names]
    sol = scipy.optimize.least_squares(residuals, x0)
    return dict(zip(names, sol.x.tolist(), strict=True))


def run_once(model: Any, data: aeroid.FlightData, fit: Any, steps: int, backend: str) -> float:
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # short runs are flagged unconverged
        res = aeroid.infer(
            model,
            data,
            PRIORS,
            noise=NOISE,
            initial=fit,
            n_walkers=16,
            n_steps=steps,
            seed=0,
            backend=backend,
        )
    dt = time.perf_counter() - t0
    assert res.samples.shape[1] == 4
    return 16 * steps / dt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--jax", action="store_true", help="also time backend='jax'")
    args = parser.parse_args()

    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0).window(0, 4)
    fit = least_squares_fit(model, data)
    print(
        f"truth case, 4 s window ({data.n_samples} samples), 16 walkers, noise given, "
        f"{args.steps} steps, started at the least-squares fit"
    )

    backends = [("numpy", model)]
    if args.jax:
        import jax.numpy as jnp

        def dyn(t: Any, x: Any, u: Any, p: Any) -> Any:
            return jnp.stack(
                [
                    p["Z_alpha"] * x[0] + x[1],
                    p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0],
                ]
            )

        jmodel = aeroid.Model(["alpha", "q"], ["elevator"], dict(catalog.SHORT_PERIOD_GUESS), dyn)
        run_once(jmodel, data, fit, 5, "jax")  # compile outside the timing
        backends.append(("jax", jmodel))
    for name, m in backends:
        rates = [run_once(m, data, fit, args.steps, name) for _ in range(args.repeats)]
        med = statistics.median(rates)
        print(
            f"backend={name:5s}  evaluations/s: median {med:8.0f}  "
            f"(min {min(rates):.0f}, max {max(rates):.0f}, {args.repeats} runs)  "
            f"target {TARGET:.0f}/s: x{med / TARGET:.2f}  "
            f"competitor {COMPETITOR:.0f}/s: x{med / COMPETITOR:.0f}"
        )


if __name__ == "__main__":
    main()
