"""Benchmark: the first call in a fresh process, with empty compilation caches (issue 47).

    python tests/benchmarks/bench_first_call.py [--repeat N]

Each case runs in its own ``python`` subprocess with the default environment,
except ``AEROID_JAX_CACHE`` pointed at a new empty folder (JAX's persistent
cache cold). Every case runs three ways:

* ``cold``: default dispatch, empty disk cache;
* ``disk``: default dispatch, a second fresh process reusing the first one's
  disk cache (the compiled programs kept across processes);
* ``numpy``: the compiled path switched off (``aeroid.models.compiled.ENABLED``):
  step-by-step RK4 with finite-difference sensitivities batched over
  parameter columns (the plain numpy Gauss-Newton of the issue's ">= 20x").

With the compiled path on, a model's first fit runs in numpy by Newton's
method over the whole record (`aeroid.models.shooting`) and queues its
compilation in the library's background thread; the second call runs in numpy
again while that compiles (issue 47 wants it within 2x the first). Newton
linearises the RK4 steps and the measurement by central differences, except
where the model gives its Jacobians in closed form: `check_compatibility`'s
kinematics and sensors (``compat``) and `aircraft.lateral` (``lat61``) do, and
their first calls take about half (compat) and two thirds (lat61) of the CPU
time the differences took, with estimates within 1e-9 (compat) and 4e-8
(lat61) relative of theirs.

Printed per case and way: the first call's wall and process CPU time, whether
JAX was imported by it, the second call and its ratio to the first, when the
background compilation was ready (from the end of the first call), and the
median of the warm calls after that, next to issue 47's targets. The cases:

* ``hfb``: an HFB-320-like nonlinear longitudinal model after Jategaonkar's
  book (11 coefficients, 7 outputs, 2 biases; `bench_nonlinear`'s model and
  seeded record, 60 s at 10 Hz); target first <= 0.7 s;
* ``otter``: a Twin Otter-like nonlinear longitudinal user model with 12
  measured inputs (7 parameters, 3 outputs, 40 s at 20 Hz, seeded); target
  first <= 0.5 s;
* ``lat61``: SIDPAC Text Example 6.1's lateral record fitted with
  `aircraft.lateral` (16 coefficients, 5 outputs, 1001 samples); needs
  ``AEROID_SIDPAC_DIR``; target first <= 0.7 s;
* ``compat``: `check_compatibility` on 60 s at 50 Hz with 12 sensor parameters
  (`bench_compatibility`'s case); target first <= 0.7 s.

Bytecode: an installed package has its modules compiled (pip writes ``.pyc``
files), so the children run with the modules precompiled into a temporary
``PYTHONPYCACHEPREFIX`` even where the caller sets ``PYTHONDONTWRITEBYTECODE``;
``--source`` keeps the caller's setting (every lazily imported module then
compiles inside the first call: about 0.05 s more).

The machine may be shared: run it several times and read the medians
(``--runs N`` repeats every case in N fresh processes and prints the median).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TARGETS = {"hfb": 0.7, "otter": 0.5, "compat": 0.7, "lat61": 0.7}

_CHILD = r"""
import json, sys, time
t_start = time.perf_counter()
sys.path.insert(0, {here!r})
import numpy as np
import aeroid
import aeroid.models.compiled as compiled
if {numpy_only!r}:
    compiled.ENABLED = False
case = {case!r}
if case == "hfb":
    import bench_nonlinear as b
    model = b.make_model()
    data = b.make_data(model)
    def call():
        return aeroid.identify(model, data, b.GUESS, estimate_bias=list(b.BIAS))
elif case == "lat61":
    import warnings
    warnings.simplefilter("ignore")
    import bench_first_call as b
    model, data, guess = b.example_6p1_case()
    x0 = dict.fromkeys(model.states, 0.0)
    def call():
        return aeroid.identify(model, data, guess, x0=x0)
elif case == "compat":
    import warnings
    warnings.simplefilter("ignore")
    sys.path.insert(0, {tests!r})
    from _compat_flight import BIASES, simulated_flight
    errors = {{**BIASES, "k_V": 0.02, "k_alpha": 0.08, "k_beta": -0.05}}
    data = simulated_flight(60.0, 50.0, errors=errors, seed=0)
    def call():
        return aeroid.check_compatibility(data, estimate=list(errors))
else:
    import bench_first_call as b
    model, data, guess = b.otter_case()
    def call():
        return aeroid.identify(model, data, guess)
setup = time.perf_counter() - t_start
w0, c0 = time.perf_counter(), time.process_time()
res = call()
first_end = time.perf_counter()
first, first_cpu = first_end - w0, time.process_time() - c0
jax_loaded = "jax" in sys.modules
first_params = {{k: float(v) for k, v in res.parameters.items()}}
calls = []
for _ in range({repeat} + 1):
    w0 = time.perf_counter()
    res = call()
    calls.append(time.perf_counter() - w0)
    if len(calls) == 1:
        # warm calls: once the background compilation the first call queued is done
        from aeroid._threads import wait_background
        wait_background()
        ready = time.perf_counter() - first_end
print(json.dumps({{"setup": setup, "first": first, "first_cpu": first_cpu, "ready": ready,
                  "second": calls[0], "warm": float(np.median(calls[1:])), "jax": jax_loaded,
                  "iterations": getattr(res, "n_iterations", getattr(res, "n_passes", 0)),
                  "estimate": first_params,
                  "warm_estimate": {{k: float(v) for k, v in res.parameters.items()}}}}))
"""


# -- the Twin Otter-like user model ---------------------------------------------------------

OTTER_TRUTH = {
    "CZ0": -0.35,
    "CZ_alpha": -5.2,
    "CZ_de": -0.45,
    "Cm0": 0.04,
    "Cm_alpha": -1.1,
    "Cm_q": -22.0,
    "Cm_de": -1.6,
}
_OTTER_INPUTS = [
    "de",
    "V",
    "theta",
    "phi",
    "beta",
    "p",
    "r",
    "flap",
    "thrust",
    "qbar",
    "mass",
    "xcg",
]


def otter_dynamics(t, x, u, p):  # type: ignore[no-untyped-def]
    """alpha, q of a Twin Otter-like aircraft driven by 12 measured channels."""
    alpha, q = x
    de, V, theta, phi, beta, pr, r, flap, thrust, qbar, mass, xcg = u
    S, cbar, Iyy = 39.0, 1.98, 3.0e4
    qh = q * cbar / (2.0 * V)
    CZ = p["CZ0"] + p["CZ_alpha"] * np.sin(alpha) + p["CZ_de"] * de - 0.8 * flap
    Cm = (
        p["Cm0"]
        + p["Cm_alpha"] * alpha
        + p["Cm_q"] * qh
        + p["Cm_de"] * de
        + CZ * (xcg - 0.25)
        + 0.002 * thrust / (qbar * S)
    )
    g = 9.81
    a_dot = (
        q
        + qbar * S * CZ / (mass * V) * np.cos(alpha)
        + g / V * np.cos(phi) * np.cos(theta - alpha)
        - (pr * np.cos(alpha) + r * np.sin(alpha)) * np.tan(beta)
    )
    q_dot = qbar * S * cbar * Cm / Iyy + pr * r * 0.1
    return np.array([a_dot, q_dot])


def otter_measurement(t, x, u, p):  # type: ignore[no-untyped-def]
    alpha, q = x
    de, flap, qbar, mass = u[0], u[7], u[9], u[10]
    CZ = p["CZ0"] + p["CZ_alpha"] * np.sin(alpha) + p["CZ_de"] * de - 0.8 * flap
    return np.array([alpha, q, qbar * 39.0 * CZ / mass])


def otter_case(seed: int = 3):  # type: ignore[no-untyped-def]
    """Model, seeded record (40 s at 20 Hz) and start values of the Twin Otter-like case."""
    import numpy as np

    import aeroid

    rng = np.random.default_rng(seed)
    t = np.arange(801) * 0.05
    n = t.size
    de = -0.03 + 0.03 * np.sign(np.sin(2 * np.pi * t / 2.5)) * ((t > 2) & (t < 12))
    de += 0.02 * np.sign(np.sin(2 * np.pi * t / 1.2)) * ((t > 20) & (t < 28))
    V = 60.0 + 0.5 * np.sin(0.1 * t)
    inputs = {
        "de": de,
        "V": V,
        "theta": 0.05 + 0.02 * np.sin(0.3 * t),
        "phi": 0.02 * np.sin(0.2 * t),
        "beta": 0.01 * np.sin(0.5 * t),
        "p": 0.01 * np.sin(0.7 * t),
        "r": 0.01 * np.cos(0.4 * t),
        "flap": np.zeros(n),
        "thrust": 8000.0 + 200.0 * np.sin(0.05 * t),
        "qbar": 0.5 * 1.1 * V**2,
        "mass": np.full(n, 5200.0),
        "xcg": np.full(n, 0.27),
    }
    model = aeroid.Model(
        ["alpha", "q"],
        _OTTER_INPUTS,
        dict(OTTER_TRUTH),
        otter_dynamics,
        outputs=["alpha", "q", "az"],
        measurement=otter_measurement,
        name="otter_longitudinal",
    )
    sim = model.simulate(t, inputs, np.array([0.06, 0.0]))
    y = sim.outputs + rng.standard_normal(sim.outputs.shape) * np.array([0.002, 0.003, 0.05])
    channels = dict(inputs)
    channels.update(alpha=y[:, 0], q=y[:, 1], az=y[:, 2])
    data = aeroid.FlightData(time=t, channels=channels)
    guess = {k: 1.25 * v for k, v in OTTER_TRUTH.items()}
    return model, data, guess


def example_6p1_case():  # type: ignore[no-untyped-def]
    """SIDPAC Text Example 6.1's lateral record with `aircraft.lateral` (SI units, the
    constants from SIDPAC's record), its CY, Cl, Cn derivatives and constant terms
    estimated from SIDPAC's start values; needs ``AEROID_SIDPAC_DIR``."""
    import scipy.io

    from aeroid import FlightData
    from aeroid.models import aircraft

    path = Path(os.environ["AEROID_SIDPAC_DIR"]) / "Text_Examples" / "example_6p1_results.mat"
    d = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    c = d["c"]
    ft, slug, slug_ft3 = 0.3048, 14.593903, 515.378818
    ci = np.asarray(c.ci, dtype=float)  # the inverse of [[Ixx, -Ixz], [-Ixz, Izz]]
    inertia = np.linalg.inv(np.array([[ci[2], ci[3]], [ci[3], ci[8]]])) * slug * ft**2
    constants = aircraft.AircraftConstants(
        mass=float(c.mass) * slug,
        Ixx=float(inertia[0, 0]),
        Iyy=0.6 * float(inertia[0, 0] + inertia[1, 1]),  # not used by the lateral model
        Izz=float(inertia[1, 1]),
        Ixz=-float(inertia[0, 1]),
        S=float(d["sarea"]) * ft**2,
        b=float(d["bspan"]) * ft,
        cbar=float(d["cbar"]) * ft,
        rho=2.0 * float(c.qbar) / float(c.vo) ** 2 * slug_ft3,
    )
    terms = {
        "CY": ["0", "beta", "r", "delta_r"],
        "Cl": ["0", "beta", "p", "r", "delta_a", "delta_r"],
        "Cn": ["0", "beta", "p", "r", "delta_a", "delta_r"],
    }
    outputs = ["beta", "p", "r", "phi", "ay"]
    model = aircraft.lateral(
        constants,
        V0=float(c.vo) * ft,
        alpha0=float(np.arcsin(c.sa)),
        theta0=float(np.arctan(c.tt)),
        terms=terms,
        outputs=outputs,
        accel_units="g",
    )
    p0 = np.asarray(d["p0"], dtype=float)
    known = ["CY_beta", "CY_r", "CY_delta_r", None, "Cl_beta", "Cl_p", "Cl_r", "Cl_delta_a"]
    known += ["Cl_delta_r", None, "Cn_beta", "Cn_p", "Cn_r", "Cn_delta_a", "Cn_delta_r"]
    guess = {n: 0.0 for n in model.parameters if n.startswith(("CY", "Cl", "Cn"))}
    guess.update({n: float(v) for n, v in zip(known, p0, strict=False) if n is not None})
    z, u = np.asarray(d["z"], dtype=float), np.asarray(d["u"], dtype=float)
    channels = {n: z[:, j] for j, n in enumerate(outputs)}
    channels.update(delta_a=u[:, 0], delta_r=u[:, 1])
    return model, FlightData(time=np.asarray(d["t"], dtype=float), channels=channels), guess


_PYC: dict[str, str] = {}  # the environment of precompiled modules (see the docstring)


def _bytecode(prefix: str) -> None:
    """Compile aeroid and the benchmark modules into `prefix`, as an installation would."""
    import aeroid

    env = dict(os.environ, PYTHONPYCACHEPREFIX=prefix)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    here = Path(__file__).resolve().parent
    dirs = [str(Path(aeroid.__file__).parent), str(here), str(here.parent)]
    code = f"import compileall\nfor d in {dirs!r}:\n    compileall.compile_dir(d, quiet=1)"
    subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True)
    _PYC.update(PYTHONPYCACHEPREFIX=prefix)


def _run(case: str, cache: str, numpy_only: bool, repeat: int) -> dict[str, object]:
    here = str(Path(__file__).resolve().parent)
    tests = str(Path(__file__).resolve().parents[1])
    code = _CHILD.format(here=here, tests=tests, numpy_only=numpy_only, case=case, repeat=repeat)
    env = dict(os.environ, AEROID_JAX_CACHE=cache, **_PYC)
    if _PYC:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True
    )
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def _median_run(case: str, numpy_only: bool, repeat: int, runs: int) -> dict[str, object]:
    """`runs` fresh processes, each with an empty disk cache: per-number medians."""
    rows = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as cache:
            rows.append(_run(case, cache, numpy_only, repeat))
    out = dict(rows[-1])
    for key in ("setup", "first", "first_cpu", "second", "ready", "warm"):
        out[key] = float(np.median([float(r[key]) for r in rows]))  # type: ignore[arg-type]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3, help="warm calls per process")
    parser.add_argument("--cases", nargs="*", default=list(TARGETS))
    parser.add_argument("--runs", type=int, default=1, help="fresh processes per case (median)")
    parser.add_argument("--source", action="store_true", help="no precompiled bytecode")
    parser.add_argument(
        "--cold-only", action="store_true", help="only the default dispatch, empty cache"
    )
    args = parser.parse_args()
    print(f"load: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as pyc:
        if not args.source:
            _bytecode(pyc)
        _cases(args)


def _cases(args: argparse.Namespace) -> None:
    for case in args.cases:
        if case == "lat61" and not os.environ.get("AEROID_SIDPAC_DIR"):
            print("lat61: skipped (AEROID_SIDPAC_DIR unset)")
            continue
        rows = {"cold": _median_run(case, False, args.repeat, args.runs)}
        if not args.cold_only:
            with tempfile.TemporaryDirectory() as cache:
                _run(case, cache, False, args.repeat)
                rows["disk"] = _run(case, cache, False, args.repeat)
            with tempfile.TemporaryDirectory() as cache:
                rows["numpy"] = _run(case, cache, True, args.repeat)
        runs = f", median of {args.runs} fresh processes" if args.runs > 1 else ""
        print(f"{case}: first-call target <= {TARGETS[case]:.2f} s{runs}")
        for way, r in rows.items():
            print(
                f"  {way:6s} first {r['first']:6.2f} s (cpu {r['first_cpu']:5.2f} s, "
                f"jax {'yes' if r['jax'] else 'no ':3s})  second {r['second']:6.2f} s "
                f"({float(r['second']) / float(r['first']):4.1f}x)  "  # type: ignore[arg-type]
                f"compiled after {r['ready']:5.2f} s  warm {r['warm']:6.3f} s  "
                f"setup {r['setup']:5.2f} s  "
                f"iterations {r['iterations']}"
            )
        ref = rows["cold"]["warm_estimate"]
        pairs = [("first call vs compiled warm", rows["cold"]["estimate"])]
        if "numpy" in rows:
            pairs.append(("step-by-step numpy vs compiled", rows["numpy"]["estimate"]))
        for label, est in pairs:
            assert isinstance(ref, dict) and isinstance(est, dict)
            rel = max(abs(est[k] - ref[k]) / max(abs(ref[k]), 1e-12) for k in ref)
            print(f"  largest relative difference of the estimates, {label}: {rel:.1e}")


if __name__ == "__main__":
    main()
