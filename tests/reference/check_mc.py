"""Is the suite's surrogate Monte Carlo a fair judge of constants and biases?

The reference suite measures our standard errors against a Monte Carlo on a
flight's own residuals: the fitted outputs plus phase-randomised surrogates
of the residuals, refitted (`_sidpac.monte_carlo`). This script asks, on
simulated records with a known truth, how that Monte Carlo and our default
bars each compare with the true sampling spread of the estimates:

(i)   ``true``: the exact first-order ``M^-1 G'SG M^-1`` with the AR(1)
      covariance ``S`` (exact for least squares; for output error ``G`` by
      central differences at the truth), beside the spread of the estimates
      over the seeds' fresh noise draws (the same inputs) that checks it;
(ii)  ``mc``: the suite's Monte Carlo on one record's own residuals, seed by
      seed: its infinite-refit value (`_sidpac.linear_mc`, exact for a
      linear fit) and, for equation error, `--mc` actual refits; and its
      expectation over noise records in closed form (`expected_mc_sd`),
      also with surrogates of the noise itself (no fit: what bin 0's
      extrapolation alone costs);
(iii) ``ours``: the default standard errors the public API returns;
(iv)  ``colores``: SIDPAC's corrected bars (the sandwich over the residuals'
      autocorrelation at every lag), their expectation in closed form.

Cases: equation error with a constant (``aeroid.equation_error``), output
error with an output bias (``identify(..., estimate_bias={"y": "output"})``
on a first-order lag), and a compatibility-like integrator with a bias on its
state equation (``estimate_bias={"y": "state"}``, the bias's sensitivity a
ramp, as the rate biases of data compatibility), each under white noise and
AR(1) noise of phi 0.9 and 0.99. For every parameter it prints the closed
forms over the truth, then for ours and the Monte Carlo the median over
seeds of ``se / true``, the root-mean-square ratio ``sqrt(mean(se^2)) /
true`` (an unbiased variance scores 1) with its standard error over seeds,
and the share of seeds within 0.8-1.25 of the truth; last, the median of
one record's ``ours / mc`` and the share of seeds where it lies within
0.8-1.25 (what the suite's target asks of one flight). It needs no data:
``python tests/reference/check_mc.py [--seeds 200] [--n 1000]``.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from scipy.linalg import toeplitz
from scipy.signal import butter, lfilter

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S

FS = 50.0
PHIS = (0.0, 0.9, 0.99)
NOISE = 0.05  # output-error noise level


def _smooth_inputs(n: int, cutoffs: tuple[float, ...], seed: int = 12345) -> np.ndarray:
    """Fixed smooth random inputs (one column per cut-off in Hz), unit variance."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, len(cutoffs)))
    for i, fc in enumerate(cutoffs):
        b, a = butter(2, fc / (FS / 2))
        x = lfilter(b, a, rng.standard_normal(n + 500))[500:]
        out[:, i] = x / x.std()
    return out


def ar1(rng: np.random.Generator, n: int, phi: float) -> np.ndarray:
    """Unit-variance AR(1) noise with a stationary start (white for phi = 0)."""
    w = rng.standard_normal(n)
    if phi == 0.0:
        return w
    w[0] /= np.sqrt(1.0 - phi**2)
    return np.asarray(lfilter([1.0], [1.0, -phi], w) * np.sqrt(1.0 - phi**2))


def exact_sd(x: np.ndarray, phi: float) -> np.ndarray:
    """Standard deviations of least squares on `x` under unit-variance AR(1) noise."""
    cov = toeplitz(phi ** np.arange(x.shape[0])) if phi else np.eye(x.shape[0])
    inv = np.linalg.inv(x.T @ x)
    return np.sqrt(np.diag(inv @ x.T @ cov @ x @ inv))


def expected_mc_sd(
    g: np.ndarray,
    phi: float,
    *,
    low_bins: int = 3,
    residuals: bool = True,
    padded: bool = False,
) -> np.ndarray:
    """The surrogate Monte Carlo's standard errors in expectation over noise records
    (infinite refits, first order), for least squares on `g` (n, p) under unit-variance
    AR(1) noise: `_sidpac.linear_mc` with each residual periodogram bin replaced by
    its expectation ``E|U_k|^2 = d_k'(I - H) S (I - H) d_k``; with `residuals`
    False, surrogates of the noise itself (``H = 0``), which leaves only the
    zero-frequency bin's extrapolation from the `low_bins` lowest. With `padded`,
    SIDPAC's colores instead: the sandwich over the residuals' biased
    autocorrelation at every lag, the same sum over the 2n-point grid with every
    bin as it is."""
    n = g.shape[0]
    size = 2 * n if padded else n
    cov = toeplitz(phi ** np.arange(n)) if phi else np.eye(n)
    m_inv = np.linalg.inv(g.T @ g)
    dft = np.fft.rfft(np.eye(n), size, axis=0)  # (bins, n): row k is d_k'
    if residuals:
        dft = dft - (dft @ g) @ m_inv @ g.T  # d_k'(I - H)
    power = np.sum((dft @ cov) * dft.conj(), axis=1).real
    vf = np.fft.rfft(g, size, axis=0) @ m_inv  # (bins, p)
    terms = 2.0 * np.abs(vf) ** 2 * power[:, None] / (size * n)
    terms[0] /= 2.0
    if size % 2 == 0:
        terms[-1] = 0.0 if not padded else terms[-1] / 2.0
    if not padded:
        k = min(low_bins, power.size - 2 + n % 2)
        terms[0] = vf[0].real ** 2 * power[1 : k + 1].mean() / n**2
    return np.sqrt(terms.sum(axis=0))


class Case:
    """One simulated study: `fit(seed)` returns estimates, our se and the Monte Carlo's."""

    name: str
    names: list[str]
    exact: np.ndarray | None = None
    expected_mc: np.ndarray | None = None
    expected_noise_mc: np.ndarray | None = None
    expected_sidpac: np.ndarray | None = None

    def fit(self, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        raise NotImplementedError


class EquationError(Case):
    """``z = c + X theta + e`` through ``aeroid.equation_error`` (intercept)."""

    def __init__(self, n: int, phi: float, refits: int) -> None:
        self.name = "equation error"
        self.n, self.phi, self.refits = n, phi, refits
        self.x = _smooth_inputs(n, (0.3, 1.0, 2.0))
        self.regs = ["x1", "x2", "x3"]
        self.names = [*self.regs, "const"]
        self.theta = np.array([1.0, -0.5, 0.25])
        design = np.column_stack([self.x, np.ones(n)])
        self.design = design
        self.pinv = np.linalg.pinv(design)
        self.exact = exact_sd(design, phi)
        self.expected_mc = expected_mc_sd(design, phi)
        self.expected_noise_mc = expected_mc_sd(design, phi, residuals=False)
        self.expected_sidpac = expected_mc_sd(design, phi, padded=True)

    def fit(self, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        import aeroid

        rng = np.random.default_rng(seed)
        z = self.x @ self.theta + 0.5 + ar1(rng, self.n, self.phi)
        data = {k: self.x[:, i] for i, k in enumerate(self.regs)} | {"z": z}
        res = aeroid.equation_error(data, "z", self.regs, intercept=True)
        est = np.array([res.parameters[k] for k in self.names])
        ours = np.array([res.stderr[k] for k in self.names])
        fitted = np.asarray(res.fitted, dtype=float)
        resid = z - fitted
        m_inv = np.linalg.inv(self.design.T @ self.design)
        lin = np.sqrt(S.linear_mc([self.design[:, None, :]], [resid[:, None]], m_inv)[0])
        mc = None
        if self.refits >= 2:
            # least squares is linear: a refit is the pseudo-inverse times the record
            mc_rng = np.random.default_rng(10_000 + seed)
            draws = [
                self.pinv @ (fitted + S.phase_surrogate(resid, mc_rng)) for _ in range(self.refits)
            ]
            mc = np.std(draws, axis=0, ddof=1)
        return est, ours, lin, mc


class OutputError(Case):
    """A first-order lag ``x' = a x + k u`` seen as ``y = x + c`` (output bias),
    or an integrator ``x' = k u + b`` (bias on the state equation), by `identify`."""

    def __init__(self, n: int, phi: float, kind: str) -> None:
        import aeroid

        self.n, self.phi, self.kind = n, phi, kind
        self.time = np.arange(n) / FS
        self.u = _smooth_inputs(n, (0.5,), seed=777)[:, 0]
        if kind == "bias":
            self.name = "output error, output bias"
            self.truth = {"a": -1.0, "k": 2.0}
            self.bias: dict[str, Any] = {"y": "output"}
            self.true_bias = 0.3

            def dyn(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
                return np.array([p["a"] * x[0] + p["k"] * u[0]])

        else:
            self.name = "integrator, state bias"
            self.truth = {"k": 1.5}
            self.bias = {"y": "state"}
            self.true_bias = 0.05

            def dyn(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
                return np.array([p["k"] * u[0]])

        self.model = aeroid.Model(
            states=["y"],
            controls=["u"],
            parameters=dict(self.truth),
            dynamics=dyn,
            outputs=["y"],
            name=f"check_mc_{kind}",
        )
        self.names = [*self.truth, "bias"]
        self.clean = self._simulate(dict(self.truth) | {"bias": self.true_bias})
        self.exact = self._exact()

    def _simulate(self, p: Mapping[str, float]) -> np.ndarray:
        """The noise-free output for parameters `p` (with ``bias``), exact for the
        piecewise-linear input (`scipy.signal.lsim`, linear interpolation)."""
        from scipy.signal import lsim

        a = p.get("a", 0.0)
        ins = np.column_stack([self.u, np.ones(self.n)])
        state_bias = p["bias"] if self.kind == "state" else 0.0
        _, y, _ = lsim(([[a]], [[p["k"], state_bias]], [[1.0]], [[0.0, 0.0]]), ins, self.time)
        return np.asarray(y) + (p["bias"] if self.kind == "bias" else 0.0)

    def _exact(self) -> np.ndarray:
        """First-order standard deviations ``sqrt(diag M^-1 G'SG M^-1)`` at the truth,
        ``G`` by central differences."""
        p0 = dict(self.truth) | {"bias": self.true_bias}
        cols = []
        for k in self.names:
            h = 1e-6 * max(abs(p0[k]), 1.0)
            up = self._simulate(p0 | {k: p0[k] + h})
            cols.append((up - self._simulate(p0 | {k: p0[k] - h})) / (2 * h))
        self.sens = np.column_stack(cols)
        self.m_inv = np.linalg.inv(self.sens.T @ self.sens)
        self.expected_mc = NOISE * expected_mc_sd(self.sens, self.phi)
        self.expected_noise_mc = NOISE * expected_mc_sd(self.sens, self.phi, residuals=False)
        self.expected_sidpac = NOISE * expected_mc_sd(self.sens, self.phi, padded=True)
        return NOISE * exact_sd(self.sens, self.phi)

    def fit(self, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        import aeroid

        rng = np.random.default_rng(seed)
        y = self.clean + NOISE * ar1(rng, self.n, self.phi)
        data = aeroid.FlightData(time=self.time, channels={"u": self.u, "y": y})
        r = aeroid.identify(
            self.model, data, dict(self.truth), x0={"y": 0.0}, estimate_bias=self.bias
        )
        (bias_se,) = r.extra_stderr.values()
        (bias,) = r.biases[0].values()
        est = np.array([*(r.parameters[k] for k in self.truth), bias])
        ours = np.array([*(r.stderr[k] for k in self.truth), bias_se])
        resid = np.asarray(r.residuals[0], dtype=float)
        # the Monte Carlo to first order: the fit is linear in the noise near the truth
        var, _ = S.linear_mc([self.sens[:, None, :]], [resid], self.m_inv)
        return est, ours, np.sqrt(var), None


def _ratios(label: str, se: np.ndarray, true: np.ndarray) -> str:
    """Median ratio, rms ratio +- its standard error, share within 0.8-1.25."""
    r = se / true
    r2 = r**2
    rms = float(np.sqrt(np.mean(r2)))
    # delta method: se of sqrt(mean) is se(mean) / (2 sqrt(mean))
    rms_se = float(np.std(r2, ddof=1) / np.sqrt(r2.size) / (2.0 * rms))
    inside = float(np.mean((r >= 0.8) & (r <= 1.25)))
    return f"{label} {np.median(r):6.3f} {rms:6.3f}+-{rms_se:5.3f} {inside:5.2f}"


def study(case: Case, seeds: int) -> list[dict[str, Any]]:
    """Run `case` over `seeds` seeds; print and return one summary row per parameter."""
    ests, ours, lins, mcs = [], [], [], []
    t0 = time.perf_counter()
    for seed in range(seeds):
        e, o, lin, mc = case.fit(seed)
        ests.append(e)
        ours.append(o)
        lins.append(lin)
        if mc is not None:
            mcs.append(mc)
    est = np.array(ests)
    spread = np.std(est, axis=0, ddof=1)
    true = case.exact if case.exact is not None else spread
    rows = []
    for j, name in enumerate(case.names):
        row: dict[str, Any] = {
            "parameter": name,
            "true": float(true[j]),
            "spread": float(spread[j]),
            "ours": np.array(ours)[:, j] / true[j],
            "lin": np.array(lins)[:, j] / true[j],
        }
        if mcs:
            row["mc"] = np.array(mcs)[:, j] / true[j]
        rows.append(row)
        line = f"  {name:<6} true {true[j]:9.3e} (spread/true {spread[j] / true[j]:5.3f})  "
        if case.expected_mc is not None:
            row["expected_mc"] = float(case.expected_mc[j] / true[j])
            line += f"E[mc]/true {row['expected_mc']:5.3f}  "
        if case.expected_noise_mc is not None:
            row["expected_noise_mc"] = float(case.expected_noise_mc[j] / true[j])
            line += f"(of the noise {row['expected_noise_mc']:5.3f})  "
        if case.expected_sidpac is not None:
            row["expected_sidpac"] = float(case.expected_sidpac[j] / true[j])
            line += f"E[colores]/true {row['expected_sidpac']:5.3f}  "
        line += _ratios("ours", np.array(ours)[:, j], true[j])
        line += "  " + _ratios("mc-lin", np.array(lins)[:, j], true[j])
        judge = np.array(mcs)[:, j] if mcs else np.array(lins)[:, j]
        if mcs:
            line += "  " + _ratios("mc", judge, true[j])
        inside = float(np.mean(np.abs(np.log(np.array(ours)[:, j] / judge)) <= np.log(1.25)))
        row["ours_mc_median"] = float(np.median(np.array(ours)[:, j] / judge))
        row["ours_mc_inside"] = inside
        line += f"  ours/mc {row['ours_mc_median']:6.3f} {inside:5.2f}"
        print(line)
    print(f"  ({time.perf_counter() - t0:.0f} s)")
    return rows


CASES: dict[str, Callable[[int, float, int], Case]] = {
    "ee": lambda n, phi, refits: EquationError(n, phi, refits),
    "oe": lambda n, phi, refits: OutputError(n, phi, "bias"),
    "compat": lambda n, phi, refits: OutputError(n, phi, "state"),
}


def structural(n: int = 1000) -> dict[str, dict[str, dict[float, dict[str, float]]]]:
    """Per judge (``mc``: the suite's Monte Carlo, ``colores``: SIDPAC's corrected
    bars), case and phi, each parameter's ``E[judge] / true`` in closed form (no
    seeds): how low that residual-based figure reads by construction."""
    out: dict[str, dict[str, dict[float, dict[str, float]]]] = {"mc": {}, "colores": {}}
    for key, make in CASES.items():
        for phi in PHIS:
            case = make(n, phi, 0)
            assert case.exact is not None
            for judge, got in (("mc", case.expected_mc), ("colores", case.expected_sidpac)):
                assert got is not None
                ratio = dict(zip(case.names, map(float, got / case.exact), strict=True))
                out[judge].setdefault(key, {})[phi] = ratio
    return out


def _span(vals: list[float]) -> str:
    lo, hi = min(vals), max(vals)
    return f"{lo:.2f}" if round(lo, 2) == round(hi, 2) else f"{lo:.2f}-{hi:.2f}"


def structural_lines(n: int = 1000) -> list[str]:
    """`structural` as one line per judge and case: constants and biases, then the rest."""
    lines = []
    for judge, table in structural(n).items():
        for key, by_phi in table.items():
            first = next(iter(by_phi.values()))
            cb = [k for k in first if k in ("const", "bias")]
            rest = [k for k in first if k not in cb]
            parts = []
            for label, names in (("/".join(cb), cb), ("others", rest)):
                vals = [_span([by_phi[phi][k] for k in names]) for phi in PHIS]
                parts.append(f"{label} {' / '.join(vals)}")
            lines.append(f"  {judge:<8}{CASE_LABELS[key]:<26} " + ";  ".join(parts))
    return lines


CASE_LABELS = {
    "ee": "equation error",
    "oe": "output error, output bias",
    "compat": "integrator, state bias",
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--n", type=int, default=1000, help="samples per record (at 50 Hz)")
    ap.add_argument("--mc", type=int, default=100, help="surrogate refits (equation error)")
    ap.add_argument("--case", action="append", choices=sorted(CASES), default=[])
    ap.add_argument("--phi", action="append", type=float, default=[])
    args = ap.parse_args(argv)
    print(
        "per parameter: median of se/true, rms ratio sqrt(mean se^2)/true +- its se over "
        "seeds, share of seeds within 0.8-1.25; true = the exact first-order sandwich, "
        "spread = the estimates' scatter over the seeds; E[.] = closed forms"
    )
    for key in args.case or list(CASES):
        for phi in args.phi or PHIS:
            case = CASES[key](args.n, phi, args.mc)
            print(f"\n{case.name}, AR(1) phi {phi}, n {args.n}, {args.seeds} seeds")
            study(case, args.seeds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
