"""Benchmark: the spec examples as a user's script runs them, each in a fresh process.

Every case runs in its own ``python`` subprocess with this process's
environment unchanged: no BLAS pinning and no thread variables set by the
benchmark, so OpenBLAS starts with its default threads, as in a user's script.
The data come from a CSV file read with `aeroid.load_flight_test` and the model
is defined inline as in the README, so the first call pays for every import it
needs. Each case prints the first call and the median of several warm calls
next to the targets of issue 28, once on a quiet machine and once with a
busy-loop process on another core ("machine busy").

Run: ``python tests/benchmarks/bench_user_process.py [--repeat N] [--quiet-only]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# case: (what is timed, warm target s, first-call target s or None)
CASES = {
    "identify": ("spec example identify (10 s, 50 Hz, 4 parameters)", 0.03, None),
    "filter_states": ("spec example filter_states (EKF + RTS)", 0.02, 0.15),
    "validate_propagate": ("validate + propagate (2000 draws)", 0.03, None),
}

_CHILD_SETUP = """
import math
import numpy as np
import aeroid


def short_period(t, x, u, p):
    alpha, q = x
    return np.array(
        [
            p["Z_alpha"] * alpha + q,
            p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0],
        ]
    )


model = aeroid.Model(
    states=["alpha", "q"],
    controls=["elevator"],
    parameters={"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -6.0},
    dynamics=short_period,
)
NAMES = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
TRUTH = {"Z_alpha": -1.2, "M_alpha": -6.0, "M_q": -2.5, "M_delta": -9.0}


def natural_frequency(p):
    return math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"])
"""


def _child(case: str, csv: str, repeat: int) -> None:
    t0 = time.perf_counter()
    import aeroid  # noqa: F401  (the user's first line)

    t_import = time.perf_counter() - t0
    scope: dict[str, object] = {}
    exec(_CHILD_SETUP, scope)  # the README's model definition
    aeroid_mod = scope["aeroid"]
    model, names = scope["model"], scope["NAMES"]
    data = aeroid_mod.load_flight_test(csv)  # type: ignore[attr-defined]

    if case == "identify":

        def call() -> object:
            return aeroid_mod.identify(model, data, names)  # type: ignore[attr-defined]

    elif case == "filter_states":
        truth = scope["TRUTH"]

        def call() -> object:
            return aeroid_mod.filter_states(  # type: ignore[attr-defined]
                model,
                data,
                truth,
                process_noise={"alpha": 1e-8, "q": 1e-8},
                measurement_noise={"alpha": 0.005**2, "q": 0.01**2},
            )

    else:
        result = aeroid_mod.identify(model, data, names)  # type: ignore[attr-defined]
        metric = scope["natural_frequency"]

        def call() -> object:
            aeroid_mod.validate(model, data, result)  # type: ignore[attr-defined]
            return aeroid_mod.propagate(  # type: ignore[attr-defined]
                result, metric, n_samples=2000, seed=0
            )

    t0 = time.perf_counter()
    call()
    first = time.perf_counter() - t0
    from _timing import timed

    warm, _ = timed(call, repeat)
    from threadpoolctl import threadpool_info

    blas = sorted({int(d["num_threads"]) for d in threadpool_info() if d["user_api"] == "blas"})
    print(json.dumps({"import": t_import, "first": first, "warm": warm, "blas": blas}))


def _run_case(case: str, csv: str, repeat: int, busy: bool) -> dict[str, float]:
    loop = None
    if busy:
        # one core kept busy for the whole run, as another program would
        loop = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(0.2)
    try:
        out = subprocess.run(
            [sys.executable, __file__, "--child", case, "--csv", csv, "--repeat", str(repeat)],
            capture_output=True,
            text=True,
            check=True,
            env=dict(os.environ),  # the caller's environment, unchanged
            cwd=Path(__file__).parent,
        )
    finally:
        if loop is not None:
            loop.kill()
            loop.wait()
    result: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--quiet-only", action="store_true", help="skip the busy-machine runs")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--csv", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args.child, args.csv, args.repeat)
        return

    from aeroid.models import catalog

    pinned = [
        v for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS") if v in os.environ
    ]
    if pinned:
        print(f"note: the caller's environment sets {pinned}; a user's default does not")
    print(f"{os.cpu_count()} CPU cores; each case in a fresh process, default environment")
    with tempfile.TemporaryDirectory(prefix="aeroid-bench-") as tmp:
        csv = str(Path(tmp) / "flight_042.csv")
        data = catalog.short_period_flight(seed=0)
        with open(csv, "w") as fh:
            fh.write("time,alpha,q,elevator\n")
            for row in zip(data.time, data["alpha"], data["q"], data["elevator"], strict=True):
                fh.write(",".join(repr(float(v)) for v in row) + "\n")
        header = (
            f"{'case':50s} {'machine':7s} {'import':>7s} {'first':>8s} {'target':>7s} "
            f"{'warm':>8s} {'target':>7s} {'BLAS thr. after':>15s}"
        )
        print(header)
        for busy in (False,) if args.quiet_only else (False, True):
            for case, (label, warm_target, first_target) in CASES.items():
                r = _run_case(case, csv, args.repeat, busy)
                ft = f"{first_target:.3f}" if first_target is not None else "—"
                print(
                    f"{label:50s} {'busy' if busy else 'quiet':7s} {r['import']:7.3f} "
                    f"{r['first']:8.4f} {ft:>7s} {r['warm']:8.4f} {warm_target:7.3f} "
                    f"{r['blas']!s:>15s}"
                )
    print("times in s: first call, then the median of the warm calls")


if __name__ == "__main__":
    main()
