"""Speed of the pre-/post-fit analyses: sensitivities, frequency response, experiment design.

Run as a script: ``python tests/benchmarks/bench_analysis.py [--repeat N]``.
Prints the median wall time of several runs of each case next to its target
and the competitor's time on the same cases.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
from _timing import median_time

import aeroid
from aeroid.models import catalog

NOISE = {"alpha": 0.005, "q": 0.01}


def case_sensitivities() -> Callable[[], object]:
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)  # the 10 s truth case
    truth = dict(catalog.SHORT_PERIOD_TRUTH)
    return lambda: aeroid.sensitivities(model, data, values=truth, noise=NOISE)


def case_frequency_response() -> Callable[[], object]:
    model = catalog.short_period()
    t = np.arange(3001) / 50.0  # 60 s at 50 Hz
    u = catalog.multisine(t, np.linspace(0.1, 4.0, 60), 0.005)
    data = catalog.short_period_flight(duration=60.0, elevator=u, seed=0)
    truth = dict(catalog.SHORT_PERIOD_TRUTH)
    return lambda: aeroid.frequency_response(model, data, truth)


def case_design() -> Callable[[], object]:
    model = catalog.short_period()
    maneuver = aeroid.Multisine("elevator", frequencies=(0.2, 0.5, 1.0, 1.5), amplitude=(0.0, 0.05))
    truth = dict(catalog.SHORT_PERIOD_TRUTH)
    return lambda: aeroid.design_experiment(
        model,
        maneuver,
        ["M_q", "M_delta"],
        values=truth,
        noise=NOISE,
        duration=8.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options={"maxiter": 4, "popsize": 3},
    )


CASES = [
    # name, factory, target (s), competitor (s)
    ("sensitivities, 10 s truth case", case_sensitivities, 0.06, 0.3),
    ("frequency_response, 60 s multisine", case_frequency_response, 0.6, 3.1),
    ("design_experiment, spec example", case_design, 3.5, 69.0),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    print(
        f"{'case':40s} {'median':>10s} {'target':>8s} {'/target':>8s} {'speed-up vs competitor':>24s}"
    )
    for name, factory, target, competitor in CASES:
        t = median_time(factory(), args.repeat, warm_up=True)
        print(f"{name:40s} {t:9.4f}s {target:7.2f}s {t / target:8.2f} {competitor / t:23.1f}x")


if __name__ == "__main__":
    main()
