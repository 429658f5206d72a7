"""Benchmark: one `filter_states` pass and the spec's filter-error fit on the truth case.

Run as ``python tests/benchmarks/bench_filter.py``. Prints the median of 5 runs
and the ratio to the issue's targets (competitor: 0.24 s and 6.4 s).
"""

from __future__ import annotations

from typing import Any

from _timing import timed

import aeroid
from aeroid.models import catalog

PROCESS = {"alpha": 1e-8, "q": 1e-8}
MEASUREMENT = {"alpha": 0.005**2, "q": 0.01**2}
NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]


def _filter_error(model: aeroid.Model, data: aeroid.FlightData) -> Any:
    if hasattr(aeroid, "identify"):
        return aeroid.identify(
            model,
            data,
            NAMES,
            method="filter_error",
            process_noise=PROCESS,
            measurement_noise=MEASUREMENT,
        )
    from aeroid.estimation._filter_error import identify_filter_error

    return identify_filter_error(
        model,
        [data],
        NAMES,
        dict(model.parameters),
        process_noise=PROCESS,
        measurement_noise=MEASUREMENT,
    )


def main() -> None:
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    truth = dict(catalog.SHORT_PERIOD_TRUTH)
    rows = []
    t, res = timed(
        lambda: aeroid.filter_states(
            model, data, truth, process_noise=PROCESS, measurement_noise=MEASUREMENT
        ),
        5,
        warm_up=True,
    )
    rows.append(("filter_states (EKF + RTS), 10 s at 50 Hz", t, 0.05, 0.24))
    t_ukf, _ = timed(
        lambda: aeroid.filter_states(
            model, data, truth, process_noise=PROCESS, measurement_noise=MEASUREMENT, method="ukf"
        ),
        5,
        warm_up=True,
    )
    rows.append(("filter_states (UKF + RTS)", t_ukf, float("nan"), float("nan")))
    t_fe, fit = timed(lambda: _filter_error(model, data), 5, warm_up=True)
    rows.append(("identify(method='filter_error')", t_fe, 0.6, 6.4))
    print(f"{'case':45s} {'median s':>10s} {'target s':>9s} {'t/target':>9s} {'competitor/t':>13s}")
    for name, tm, target, comp in rows:
        print(f"{name:45s} {tm:10.4f} {target:9.3g} {tm / target:9.2f} {comp / tm:13.1f}")
    print(f"filter-error fit: {fit.n_iterations} iterations, sigma2 = {fit.sigma2:.3f}")
    print(f"log-likelihood of the filter pass: {res.log_likelihood:.6g}")


if __name__ == "__main__":
    main()
