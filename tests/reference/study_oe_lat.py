"""Why our default error bars on SIDPAC's oe_lat demo depart from its Monte Carlo.

The demo (`ref_demo_oe_lat.py`) fits five outputs whose residuals are
coloured (lag-one correlations 0.11-0.92) and, on phi, drift like a random
walk (0.9994) that the phi state bias, a ramp, cannot absorb. Against the
suite's Monte Carlo (refits of the fitted outputs plus phase-randomised
residuals) ours read 0.60-0.84 on the side-force and N_beta rows and
1.27-1.57 on L_r and N_delta_a. Two studies on the demo's own fit:

``decompose``: for the same surrogates, the spread of the refits (the noise
covariance re-estimated from each refit's residuals, as `identify` does),
of refits with the output weights held at the flight's, and of the fit's
first-order response ``M^-1 G'R^-1 s``, which is what every sandwich -- ours,
SIDPAC's colores, the raw-periodogram `linear_mc` -- estimates. Held
weights give the first order back; the gap is the weights' own scatter.

``truth``: seeded records with a known truth, the fit's outputs plus noise
shaped like its residuals (per output an AR(1) at the residual's lag-one
correlation and variance; on phi a random walk plus white noise with the
residual's difference variance and lag-one difference covariance), each
fitted with the default bars; the true standard error is the estimates'
scatter over the seeds. With ``weights='estimated'`` the fit estimates the
noise covariance as a user's would; with ``'held'`` it is fixed at the
flight's. For the first `--mc-seeds` seeds the suite's Monte Carlo is run
on that record too (``mc/true``): whether it is a fair judge under a random
walk. Coverage takes our t intervals (`margins`).

``AEROID_SIDPAC_DIR=... python tests/reference/study_oe_lat.py [--decompose 100]
[--seeds 150] [--mc-seeds 0] [--refits 40] [--weights both]``.
"""

from __future__ import annotations

import argparse
import contextlib
import pathlib
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _sidpac as S
import ref_demo_oe_lat as R

STATE_BIAS = "bias.state.phi"
OUTPUT_BIAS = "bias.ay"


@dataclass
class Fit:
    """The demo's fit as `ref_demo_oe_lat.run` makes it, with the kernel's inputs."""

    model: Any
    flight: Callable[[np.ndarray], Any]
    z: np.ndarray
    result: Any
    outputs: tuple[str, ...]
    options: dict[str, Any]
    sens: np.ndarray  # (n, n_y, p), weighted as the kernel got them
    m_inv: np.ndarray
    root: np.ndarray  # each output's noise standard deviation, the weighting
    drift: Any  # the fit's ResidualDriftWarning, if it gave one

    @property
    def residuals(self) -> np.ndarray:
        return S.output_residuals(self.result, self.outputs)

    @property
    def keys(self) -> list[str]:
        return [*self.result.parameters, STATE_BIAS, OUTPUT_BIAS]

    def held(self) -> dict[str, float]:
        """`identify`'s ``weights`` that hold the noise covariance at the flight's."""
        return {o: float(self.root[k] ** -2) for k, o in enumerate(self.outputs)}


def _estimates(result: Any, keys: list[str]) -> np.ndarray:
    e = S.estimates_with_biases(result)
    return np.array([e[k] for k in keys])


def _stderr_dof(result: Any, keys: list[str]) -> tuple[np.ndarray, np.ndarray]:
    extra = {STATE_BIAS: "bias[0].state.phi", OUTPUT_BIAS: "bias[0].ay"}
    dof_key = {STATE_BIAS: "x0[0].bias.phi", OUTPUT_BIAS: "bias[0].ay"}
    se = [result.extra_stderr[extra[k]] if k in extra else result.stderr[k] for k in keys]
    nu = [result.degrees_of_freedom.get(dof_key.get(k, k), np.inf) for k in keys]
    return np.array(se, dtype=float), np.array(nu, dtype=float)


@contextlib.contextmanager
def _captured(found: dict[str, Any]) -> Iterator[None]:
    """Record the demo's fit (its Monte Carlo call) and the kernel's inputs."""
    import aeroid._colour as colour

    saved_mc, saved_kernel = S.identify_monte_carlo, colour.colored_covariance

    def fake_mc(
        model: Any, flight: Any, z: Any, res: Any, outputs: Any, n: int, **kw: Any
    ) -> dict[str, float]:
        kw.pop("seed", None)
        found.update(model=model, flight=flight, z=z, result=res, outputs=tuple(outputs))
        found["options"] = kw
        return {}

    def kernel(sens: Any, resid: Any, m_inv: Any, **kw: Any) -> Any:
        found.setdefault("kernel", (sens, resid, m_inv))
        return saved_kernel(sens, resid, m_inv, **kw)

    S.identify_monte_carlo = fake_mc
    colour.colored_covariance = kernel  # type: ignore[assignment]
    try:
        yield
    finally:
        S.identify_monte_carlo = saved_mc
        colour.colored_covariance = saved_kernel  # type: ignore[assignment]


def demo_fit(folder: pathlib.Path) -> Fit:
    found: dict[str, Any] = {}
    with _captured(found), warnings.catch_warnings(record=True) as told:
        warnings.simplefilter("always")
        R.run(folder, mc=0)
    drift = [w.message for w in told if hasattr(w.message, "widening")]
    found["drift"] = drift[0] if drift else None
    sens, wres, m_inv = found.pop("kernel")
    resid = S.output_residuals(found["result"], found["outputs"])
    root = np.array([np.std(resid[:, k]) / np.std(wres[0][:, k]) for k in range(resid.shape[1])])
    return Fit(sens=np.asarray(sens[0]), m_inv=np.asarray(m_inv), root=root, **found)


def _refit(fit: Fit, z: np.ndarray, start: dict[str, float], **extra: Any) -> Any:
    import aeroid

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return aeroid.identify(fit.model, fit.flight(z), start, **fit.options, **extra)


def decompose(fit: Fit, refits: int, seed: int = 0) -> None:
    """Refits with the weights estimated and held against the first order, same draws."""
    rng = np.random.default_rng(seed)
    resid = fit.residuals
    fitted = fit.z - resid
    keys = fit.keys
    start = dict(fit.result.parameters)
    theta = _estimates(fit.result, keys)
    first, est, held, noise = [], [], [], []
    for _ in range(refits):
        s = S.phase_surrogate(resid, rng)
        first.append(fit.m_inv @ np.einsum("tap,ta->p", fit.sens, s / fit.root))
        r_est = _refit(fit, fitted + s, start, error_bars="white")
        est.append(_estimates(r_est, keys) - theta)
        noise.append(np.diag(r_est.noise_covariance) / fit.root**2)
        r_held = _refit(fit, fitted + s, start, error_bars="white", weights=fit.held())
        held.append(_estimates(r_held, keys) - theta)
    sd_first = np.std(first, axis=0, ddof=1)
    sd_est = np.std(est, axis=0, ddof=1)
    sd_held = np.std(held, axis=0, ddof=1)
    ours, _ = _stderr_dof(fit.result, keys)
    lin = np.sqrt(S.linear_mc([fit.sens], [resid / fit.root], fit.m_inv)[0])
    print(
        f"\n== decompose: {refits} surrogates of the flight's residuals, the same for each column"
    )
    head = ("refit/1st", "held/1st", "ours/refit", "ours/held", "ours/1st", "ours/lin")
    print(f"{'parameter':<16}" + "".join(f"{h:>11}" for h in head))
    for j, k in enumerate(keys):
        vals = (
            sd_est[j] / sd_first[j],
            sd_held[j] / sd_first[j],
            ours[j] / sd_est[j],
            ours[j] / sd_held[j],
            ours[j] / sd_first[j],
            ours[j] / lin[j],
        )
        print(f"{k:<16}" + "".join(f"{v:11.3f}" for v in vals))
    print(
        "refit: the weights re-estimated per refit (the suite's Monte Carlo); held: fixed at the "
        "flight's; 1st: M^-1 G'R^-1 s on the same surrogates; lin: its infinite-refit value"
    )
    ratio = np.array(noise)
    print("the refits' noise variances over the flight's, mean (sd) per output:")
    print(
        "  "
        + ", ".join(
            f"{o} {m:.3f} ({d:.3f})"
            for o, m, d in zip(
                fit.outputs, ratio.mean(axis=0), ratio.std(axis=0, ddof=1), strict=True
            )
        )
    )


def widening(fit: Fit) -> None:
    """The drift warning's widening factor against the bars themselves: the default
    standard errors over those of the same fit with ``error_bars='white'``."""
    keys = fit.keys
    white = _refit(fit, fit.z, dict(fit.result.parameters), error_bars="white")
    ratio = _stderr_dof(fit.result, keys)[0] / _stderr_dof(white, keys)[0]
    j = int(np.argmax(ratio))
    told = "no drift warning" if fit.drift is None else f"the warning says {fit.drift.widening:.3f}"
    print(f"\n== widening: default over white bars up to {ratio[j]:.3f} (on {keys[j]}); {told}")
    print("  " + ", ".join(f"{k} {v:.2f}" for k, v in zip(keys, ratio, strict=True)))


def _noise_model(resid: np.ndarray, walk: int) -> Callable[[np.random.Generator], np.ndarray]:
    """Noise shaped like `resid`: AR(1) per output at its lag-one correlation and
    variance; output `walk` a random walk plus white noise whose differences have the
    residual's difference variance and lag-one covariance."""
    n, m = resid.shape
    lag = np.array([resid[:-1, k] @ resid[1:, k] / (resid[:, k] @ resid[:, k]) for k in range(m)])
    sd = resid.std(axis=0)
    d = np.diff(resid[:, walk])
    white = float(np.sqrt(max(-np.mean(d[1:] * d[:-1]), 0.0)))
    step = float(np.sqrt(max(d.var() - 2.0 * white**2, 0.0)))

    def draw(rng: np.random.Generator) -> np.ndarray:
        out = np.empty((n, m))
        for k in range(m):
            if k == walk:
                w = rng.standard_normal((2, n))
                out[:, k] = step * np.cumsum(w[0]) + white * w[1]
                continue
            e = rng.standard_normal(n) * sd[k] * np.sqrt(1.0 - lag[k] ** 2)
            e[0] = sd[k] * rng.standard_normal()
            out[:, k] = lfilter([1.0], [1.0, -lag[k]], e)
        return out

    return draw


def truth(fit: Fit, seeds: int, weights: str, mc_seeds: int, refits: int) -> None:
    """Seeded known-truth records: ours and (for `mc_seeds`) the Monte Carlo over the truth."""
    from aeroid._stats import t_quantile

    draw = _noise_model(fit.residuals, fit.outputs.index("phi"))
    fitted = fit.z - fit.residuals
    keys = fit.keys
    theta = _estimates(fit.result, keys)
    start = dict(fit.result.parameters)
    extra = {"weights": fit.held()} if weights == "held" else {}
    est, ses, cover, mcs = [], [], [], []
    t0 = time.perf_counter()
    for s in range(seeds):
        z = fitted + draw(np.random.default_rng(1000 + s))
        r = _refit(fit, z, start, **extra)
        e = _estimates(r, keys)
        se, nu = _stderr_dof(r, keys)
        est.append(e)
        ses.append(se)
        cover.append(np.abs(e - theta) <= t_quantile(nu) * se)
        if s < mc_seeds:
            got = S.identify_monte_carlo(
                fit.model, fit.flight, z, r, fit.outputs, refits, seed=s, **fit.options, **extra
            )
            mcs.append([got.get(k, np.nan) for k in keys])
    true = np.std(est, axis=0, ddof=1)
    ratio = np.array(ses) / true
    print(
        f"\n== truth: {seeds} seeds, weights {weights}, random-walk phi "
        f"({time.perf_counter() - t0:.0f} s)"
    )
    head = ["true se", "ours rms", "median", "coverage"] + (["mc rms", "mc median"] if mcs else [])
    print(f"{'parameter':<16}" + "".join(f"{h:>10}" for h in head))
    for j, k in enumerate(keys):
        vals = [
            S._fmt(true[j], 10, 3),
            f"{np.sqrt(np.mean(ratio[:, j] ** 2)):10.3f}",
            f"{np.median(ratio[:, j]):10.3f}",
            f"{np.mean(np.array(cover)[:, j]):10.3f}",
        ]
        if mcs:
            m = np.array(mcs)[:, j] / true[j]
            vals += [f"{np.sqrt(np.nanmean(m**2)):10.3f}", f"{np.nanmedian(m):10.3f}"]
        print(f"{k:<16}" + "".join(vals))
    print(
        "true se: the estimates' scatter over the seeds (its own relative se "
        f"{1 / np.sqrt(2 * (seeds - 1)):.3f}); ours/mc rms: sqrt(mean(se^2))/true; coverage: "
        "our 95 % t intervals"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--decompose", type=int, default=100, help="surrogates (0 skips)")
    ap.add_argument("--refits", type=int, default=40, help="refits per seed's Monte Carlo")
    ap.add_argument("--seeds", type=int, default=150, help="known-truth records (0 skips)")
    ap.add_argument("--mc-seeds", type=int, default=0, help="of them, with the Monte Carlo")
    ap.add_argument("--weights", choices=("estimated", "held", "both"), default="both")
    args = ap.parse_args(argv)
    folder = S.data_folder()
    if folder is None:
        print(f"skipped: set {S.ENV} to the SIDPAC V2.0 folder")
        return 0
    fit = demo_fit(folder)
    widening(fit)
    if args.decompose >= 2:
        decompose(fit, args.decompose)
    if args.seeds >= 2:
        for w in ("estimated", "held") if args.weights == "both" else (args.weights,):
            truth(fit, args.seeds, w, args.mc_seeds, args.refits)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
