"""Low-order equivalent-system fits (`aeroid.frequency.handling_qualities.equivalent_system`):
the standard forms' parameters from the polynomial ones with their delta-method
errors, the Hodgkinson mismatch, and the multi-start global fit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from ..errors import IdentificationError
from ..io.data import FlightData
from ._rational_fit import _coherence_weight, _levy_sk, _Structure
from ._response_records import TransferFunctionFit

FloatArray = NDArray[np.float64]


# Delays tried by the global start: a grid up to half a turn of phase at the top
# frequency, and the number of the best rational fits refined nonlinearly.
_DELAY_GRID = 13
_STARTS = 4
# Among final fits whose cost is within this factor of the lowest, a physical one
# (minimum-phase zero, τ ≥ 0) is preferred.
_CLOSE = 1.1


def _loes_parameters(kind: str, p: Mapping[str, float]) -> dict[str, float]:
    """The equivalent-system parameters from the polynomial ones."""
    tau = float(p.get("tau", 0.0))
    nan = float("nan")
    if kind == "roll":
        return {"K": p["b0"], "1/T_R": p["a0"], "tau": tau}
    omega = float(np.sqrt(p["a0"])) if p["a0"] > 0 else nan
    zeta = p["a1"] / (2.0 * omega) if p["a0"] > 0 else nan
    if kind == "short_period":
        k = p["b1"]
        return {
            "K": k,
            "1/T_theta2": p["b0"] / k if k != 0 else nan,
            "zeta": zeta,
            "omega": omega,
            "tau": tau,
        }
    return {"K": p["b0"], "zeta": zeta, "omega": omega, "tau": tau}


def _derived(kind: str, p: Mapping[str, float]) -> dict[str, float]:
    """`_loes_parameters` and, for the short period, T_theta2."""
    out = _loes_parameters(kind, p)
    if kind == "short_period":
        out["T_theta2"] = p["b1"] / p["b0"] if p["b0"] != 0 else float("nan")
    return out


def _delta_method(kind: str, fit: TransferFunctionFit) -> dict[str, float]:
    """Standard errors of the derived parameters: sqrt(diag(G Σ Gᵀ))."""
    keys, cov = _delta_covariance(kind, fit)
    with np.errstate(invalid="ignore"):
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return dict(zip(keys, se.tolist(), strict=True))


def _delta_covariance(kind: str, fit: TransferFunctionFit) -> tuple[list[str], FloatArray]:
    """The derived parameters' names and covariance G Σ Gᵀ, G by central differences."""
    names = list(fit.parameters)
    theta = np.array([fit.parameters[k] for k in names], dtype=np.float64)
    cov = np.asarray(fit.covariance, dtype=np.float64)
    base = _derived(kind, fit.parameters)
    keys = list(base)
    g = np.zeros((len(keys), theta.size))
    for j in range(theta.size):
        step = 1e-6 * max(abs(theta[j]), 1e-3)
        hi, lo = theta.copy(), theta.copy()
        hi[j] += step
        lo[j] -= step
        up = _derived(kind, dict(zip(names, hi.tolist(), strict=True)))
        down = _derived(kind, dict(zip(names, lo.tolist(), strict=True)))
        g[:, j] = [(up[k] - down[k]) / (2.0 * step) for k in keys]
    with np.errstate(invalid="ignore"):
        return keys, np.asarray(g @ cov @ g.T, dtype=np.float64)


def _mismatch(fit: TransferFunctionFit, p: Mapping[str, float]) -> float:
    """Hodgkinson/CIFER mismatch J of the transfer function `p` against the fit's points."""
    w = np.asarray(fit.frequency, dtype=np.float64)
    h = np.asarray(fit.response, dtype=np.complex128)
    keys = list(fit.parameters)
    m = sum(k.startswith("b") for k in keys) - 1
    n = sum(k.startswith("a") for k in keys)
    st = _Structure(m, n, "tau" in p, w)
    theta = np.array([p[k] for k in keys], dtype=np.float64)
    with np.errstate(all="ignore"):
        d = np.log(h) - st.log_response(theta)[0]
        j = (20.0 / w.size) * np.sum(
            _coherence_weight(np.asarray(fit.coherence, dtype=np.float64))
            * (
                (20.0 / np.log(10.0) * d.real) ** 2
                + 0.01745 * np.degrees(np.angle(np.exp(1j * d.imag))) ** 2
            )
        )
    return float(j) if np.isfinite(j) else float("inf")


def _cifer_cost(fit: TransferFunctionFit) -> float:
    return fit.cost


def _fourier_residual(
    data: FlightData, input: str | None, output: str | None
) -> Callable[[TransferFunctionFit], float]:
    """The objective of a Fourier-transform fit, Σ |Y − T U|², at the fit's frequencies."""
    from ._rational_fit import _detrended, _end_basis, _without_ends
    from .frequency_domain import _transform

    dt = float(np.mean(np.diff(data.time)))
    span = dt * (data.n_samples - 1)
    u = _detrended(data.time, np.asarray(data[str(input)], dtype=np.float64))
    y = _detrended(data.time, np.asarray(data[str(output)], dtype=np.float64))

    def cost(fit: TransferFunctionFit) -> float:
        w = np.asarray(fit.frequency, dtype=np.float64)
        big_u = _transform(u[:, None], dt, w, cubic=False)[:, 0]
        big_y = _transform(y[:, None], dt, w, cubic=True)[:, 0]
        r = big_y - fit.evaluate(w) * big_u
        if fit.ends_estimated:
            # the ends are linear given the transfer function: what they leave
            order = max(len(fit.numerator), len(fit.denominator)) - 1
            basis = _end_basis(w, span, order)
            if basis is not None:
                den = np.polyval(np.asarray(fit.denominator, dtype=np.float64), 1j * w)
                r = _without_ends(r, basis / den[:, None])
        return float(np.sum(np.abs(r) ** 2))

    return cost


def _physical(kind: str, p: Mapping[str, float]) -> bool:
    if p.get("tau", 0.0) < 0:
        return False
    return not (kind == "short_period" and p["b1"] != 0 and p["b0"] / p["b1"] < 0)


def _global_fit(
    fitter: Callable[[Mapping[str, float] | None], TransferFunctionFit],
    objective: Callable[[TransferFunctionFit], float],
    kind: str,
    m: int,
    n: int,
    delay: bool,
) -> TransferFunctionFit:
    """The fit from several starts: linear rational fits over a grid of delays.

    For each delay on a grid from 0 to half a turn of phase at the top frequency,
    a Sanathanan-Koerner (iterated Levy) fit of the rational form to H(jω) e^{jωτ};
    those with stable poles, ranked by their mismatch, start the nonlinear fit. The
    lowest final cost wins, a physical solution preferred among costs within 10 %.
    """
    base = fitter(None)
    w = np.asarray(base.frequency, dtype=np.float64)
    h = np.asarray(base.response, dtype=np.complex128)
    weight = _coherence_weight(np.asarray(base.coherence, dtype=np.float64))
    st = _Structure(m, n, False, w)
    names = list(base.parameters)
    taus = np.linspace(0.0, np.pi / float(w.max()), _DELAY_GRID) if delay else np.zeros(1)
    ranked: list[tuple[float, dict[str, float]]] = []
    for tau in taus:
        with np.errstate(all="ignore"):
            theta = _levy_sk(st, h * np.exp(1j * w * tau), weight)
        poles = np.roots(np.concatenate([[1.0], theta[m + 1 :][::-1]]))
        if not (np.all(np.isfinite(theta)) and np.all(poles.real < 0)):
            continue
        cand = dict(zip(names, [*theta.tolist(), float(tau)][: len(names)], strict=True))
        ranked.append((_mismatch(base, cand), cand))
    ranked.sort(key=lambda c: c[0])
    fits = [base]
    for _, cand in ranked[:_STARTS]:
        try:
            fits.append(fitter(cand))
        except IdentificationError:
            continue  # a start that diverges is no candidate

    costs = [objective(f) for f in fits]
    best = min(costs)
    close = [
        f
        for f, c in zip(fits, costs, strict=True)
        if c <= _CLOSE * best and _physical(kind, f.parameters)
    ]
    if close:
        return min(close, key=objective)
    return fits[int(np.argmin(costs))]
