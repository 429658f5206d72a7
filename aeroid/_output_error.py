"""Maximum-likelihood output-error estimation (Gauss–Newton with relaxation).

The unknowns are the model parameters, optionally each manoeuvre's initial
states and per-output measurement biases. The measurement-noise covariance is
concentrated out of the likelihood (estimated from the residuals at every
iteration) unless fixed weights are given, so the cost is
``sum_k N/2 ln(mean residual_k^2)``. Each iteration costs one batched
simulation per manoeuvre: the trial point together with its central
finite-difference columns.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .data import FlightData
from .errors import IdentifiabilityWarning, IdentificationError
from .identification import IdentificationResult

FloatArray = NDArray[np.float64]

SIMULATE_OPTIONS = ("method", "substeps", "rtol", "atol")
_IDENTIFIABILITY_RCOND = 1e-9
# Residuals count as coloured when a lag-one correlation is significant (3/sqrt(N)),
# which makes the estimated correlation time exceed 1.
_WHITE_TAU = 1.0


@dataclass
class _Manoeuvre:
    data: FlightData
    time: FloatArray
    controls: FloatArray  # (n_t, n_u)
    measured: FloatArray  # (n_t, n_y)
    x0: FloatArray  # (n_x,) current initial state
    x0_free: list[int]  # indices of estimated states
    bias: FloatArray  # (n_y,)
    bias_free: list[int]


@dataclass
class _Layout:
    """Where each unknown sits in the stacked vector theta."""

    names: list[str]  # model parameters
    n_p: int
    x0_slices: list[slice]
    bias_slices: list[slice]
    n_total: int


def _typical_scales(
    layout: _Layout, theta: FloatArray, mans: list[_Manoeuvre], state_idx: list[int]
) -> FloatArray:
    typ = np.ones(layout.n_total)
    typ[: layout.n_p] = np.maximum(np.abs(theta[: layout.n_p]), 1e-3)
    for m, sx, sb in zip(mans, layout.x0_slices, layout.bias_slices, strict=True):
        stds = np.std(m.measured, axis=0) + 1e-12
        for j, s in zip(range(sx.start, sx.stop), m.x0_free, strict=True):
            k = state_idx[s]
            typ[j] = stds[k] if k >= 0 else 1.0
        for j, k in zip(range(sb.start, sb.stop), m.bias_free, strict=True):
            typ[j] = stds[k]
    return typ


def _simulate_members(
    model: Any,
    man: _Manoeuvre,
    params: Mapping[str, FloatArray],
    x0: FloatArray,
    out_idx: list[int],
    options: Mapping[str, Any],
    errors: list[str] | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Outputs (B, n_t, n_y) and ok mask for a batch of parameter/x0 members; what a
    stepped simulator raised is appended to `errors`."""
    if hasattr(model, "simulate_batch"):
        sim = model.simulate_batch(man.time, man.controls, x0, params, **options)
        return sim.outputs[:, :, out_idx], sim.ok
    # A stepped simulator: one run per member.
    batch = x0.shape[0]
    outs = np.full((batch, man.time.size, len(out_idx)), np.nan)
    ok = np.zeros(batch, dtype=bool)
    ctrl = {c: man.controls[:, j] for j, c in enumerate(model.controls)}
    for b in range(batch):
        p = {k: float(v[b]) for k, v in params.items()}
        try:
            res = model.simulate(man.time, ctrl, None, p, **options)
        except Exception as exc:  # a failed member is a rejected point, not a crash
            if errors is not None:
                errors.append(f"{type(exc).__name__}: {exc}")
            continue
        y = np.asarray(res.outputs)[:, out_idx]
        if np.all(np.isfinite(y)):
            outs[b] = y
            ok[b] = True
    return outs, ok


class _Problem:
    def __init__(
        self,
        model: Any,
        mans: list[_Manoeuvre],
        layout: _Layout,
        out_idx: list[int],
        fixed: Mapping[str, float],
        options: Mapping[str, Any],
        gradient: str,
    ) -> None:
        self.model = model
        self.mans = mans
        self.layout = layout
        self.out_idx = out_idx
        self.fixed = dict(fixed)
        self.options = dict(options)
        self.gradient = gradient
        self.errors: list[str] = []  # what a stepped simulator raised, for messages

    def unpack(self, theta: FloatArray, i: int) -> tuple[FloatArray, FloatArray]:
        m = self.mans[i]
        x0 = m.x0.copy()
        x0[m.x0_free] = theta[self.layout.x0_slices[i]]
        b = m.bias.copy()
        b[m.bias_free] = theta[self.layout.bias_slices[i]]
        return x0, b

    def evaluate(
        self, theta: FloatArray, steps: FloatArray | None
    ) -> tuple[list[FloatArray], list[FloatArray] | None, bool]:
        """Residuals per manoeuvre at theta and, when steps are given, dv/dtheta.

        Returns (residuals [n_t, n_y], jacobians [n_t, n_y, n_total] of the
        residual, ok).
        """
        lay = self.layout
        residuals: list[FloatArray] = []
        jacobians: list[FloatArray] | None = [] if steps is not None else None
        for i, m in enumerate(self.mans):
            x0, bias = self.unpack(theta, i)
            sx = lay.x0_slices[i]
            # simulated columns: model parameters and this manoeuvre's initial states
            cols = list(range(lay.n_p)) + list(range(sx.start, sx.stop))
            if steps is not None and self.gradient == "jax":
                from . import _jax

                p = dict(self.fixed)
                p.update({n: float(theta[j]) for j, n in enumerate(lay.names)})
                y, jac_p = _jax.outputs_and_jacobian(
                    self.model, m.time, m.controls, x0, p, lay.names
                )
                y = np.asarray(y)[:, self.out_idx]
                jac_p = np.asarray(jac_p)[:, self.out_idx, :]
                if not np.all(np.isfinite(y)):
                    return [], None, False
                v = m.measured - y - bias
                jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                jac[:, :, : lay.n_p] = -jac_p
                residuals.append(v)
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
                continue
            n_cols = len(cols) if steps is not None else 0
            batch = 1 + 2 * n_cols
            P = {n: np.full(batch, theta[j]) for j, n in enumerate(lay.names)}
            X0 = np.repeat(x0[None, :], batch, axis=0)
            if steps is not None:
                for c, j in enumerate(cols):
                    h = steps[j]
                    for sign, b in ((1.0, 1 + 2 * c), (-1.0, 2 + 2 * c)):
                        if j < lay.n_p:
                            P[lay.names[j]][b] += sign * h
                        else:
                            X0[b, m.x0_free[j - sx.start]] += sign * h
            outs, ok = _simulate_members(
                self.model, m, P, X0, self.out_idx, self.options, self.errors
            )
            if not ok[0]:
                return [], None, False
            v = m.measured - outs[0] - bias
            residuals.append(v)
            if steps is not None:
                if not np.all(ok):
                    return [], None, False
                jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                for c, j in enumerate(cols):
                    jac[:, :, j] = -(outs[1 + 2 * c] - outs[2 + 2 * c]) / (2 * steps[j])
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
        return residuals, jacobians, True

    def _bias_columns(self, jac: FloatArray, i: int) -> None:
        sb = self.layout.bias_slices[i]
        for j, k in zip(range(sb.start, sb.stop), self.mans[i].bias_free, strict=True):
            jac[:, k, j] = -1.0


def _noise_variances(residuals: list[FloatArray], floor: FloatArray) -> FloatArray:
    stacked = np.concatenate(residuals, axis=0)
    return np.maximum(np.mean(stacked**2, axis=0), floor)


def _ml_cost(residuals: list[FloatArray], fixed_r: FloatArray | None, floor: FloatArray) -> float:
    stacked = np.concatenate(residuals, axis=0)
    n = stacked.shape[0]
    if fixed_r is None:
        r = np.maximum(np.mean(stacked**2, axis=0), floor)
        return float(0.5 * n * np.sum(np.log(r)))
    return float(0.5 * np.sum(stacked**2 / fixed_r))


def _information(jacobians: list[FloatArray], r: FloatArray) -> FloatArray:
    m = np.zeros((jacobians[0].shape[2],) * 2)
    for jac in jacobians:
        w = jac / np.sqrt(r)[None, :, None]
        flat = w.reshape(-1, w.shape[2])
        m += flat.T @ flat
    return m


def _gradient(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray
) -> FloatArray:
    g = np.zeros(jacobians[0].shape[2])
    for jac, v in zip(jacobians, residuals, strict=True):
        g += np.einsum("tkp,tk->p", jac, v / r[None, :])
    return g


def _bandwidth(v: FloatArray) -> tuple[int, float]:
    """Lag window and correlation time for the coloured-residual correction.

    The correlation time comes from the lag-one autocorrelation through the
    AR(1) relation tau = (1 + rho) / (1 - rho), a far steadier statistic than a
    windowed sum; the window spans five correlation times.
    """
    n = v.shape[0]
    tau_max = 1.0
    for k in range(v.shape[1]):
        x = v[:, k]
        c0 = float(x @ x)
        if c0 <= 0:
            continue
        rho = min(float(x[:-1] @ x[1:]) / c0, 0.99)
        if rho > 3.0 / np.sqrt(n):  # significant correlation only
            tau_max = max(tau_max, (1.0 + rho) / (1.0 - rho))
    lags = int(np.ceil(5.0 * tau_max)) if tau_max > 1.0 else 0
    return int(min(lags, n // 3)), tau_max


def _colored_covariance(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray, m_inv: FloatArray
) -> FloatArray:
    """Morelli's covariance for coloured residuals.

    ``M^-1 [sum_ij J_i' R^-1 Rvv(i-j) R^-1 J_j] M^-1`` where ``Rvv`` is the
    residual auto- and cross-correlation estimated from the whole record and
    the double sum runs over lags up to a few correlation times.
    """
    n_par = m_inv.shape[0]
    middle = np.zeros((n_par, n_par))
    for jac, v in zip(jacobians, residuals, strict=True):
        n = v.shape[0]
        lags, tau = _bandwidth(v)
        # Fitted residuals are orthogonal to the sensitivities, which hides part of
        # the noise; with N/tau effectively independent samples the usual N/(N-p)
        # degrees-of-freedom correction becomes N_eff/(N_eff - p).
        n_eff = n / max(tau, 1.0)
        dof = n_eff / max(n_eff - n_par, 0.5 * n_eff)
        w = jac / r[None, :, None]  # (n_t, n_y, n_par)
        # No mean removal: for coloured noise the sample mean is itself a slow
        # error component, and subtracting it would bias every lag low.
        vc = v
        for lag in range(lags + 1):
            # r_kl(lag) = E[v_k(t) v_l(t+lag)], C_kl(lag) = sum_t w_k(t) w_l(t+lag)'
            rv = vc[: n - lag].T @ vc[lag:] / n  # (n_y, n_y)
            c = dof * np.einsum("tkp,tlq,kl->pq", w[: n - lag], w[lag:], rv)
            middle += c if lag == 0 else c + c.T
    return m_inv @ middle @ m_inv


def _combinations(m: FloatArray, names: Sequence[str]) -> tuple[list[tuple[str, ...]], FloatArray]:
    """Near-null directions of the normalised information matrix, as name groups."""
    d = np.sqrt(np.clip(np.diag(m), 0, None))
    zero = d <= 0
    d_safe = np.where(zero, 1.0, d)
    mn = m / np.outer(d_safe, d_safe)
    mn[zero, :] = 0
    mn[:, zero] = 0
    evals, evecs = np.linalg.eigh(mn)
    top = max(float(evals[-1]), 1e-300)
    combos: list[tuple[str, ...]] = []
    null = np.zeros(m.shape[0], dtype=bool)
    for j in np.flatnonzero(zero).tolist():
        combos.append((names[j],))
        null[j] = True
    for k in np.flatnonzero(evals < _IDENTIFIABILITY_RCOND * top):
        vec = evecs[:, k]
        if float(np.sum(vec[zero] ** 2)) > 0.81:
            continue  # the direction of a parameter already listed as insensitive
        big = np.flatnonzero(np.abs(vec) > 0.1 * np.max(np.abs(vec))).tolist()
        members = [j for j in big if not zero[j]]
        if members:
            combos.append(tuple(names[j] for j in members))
            null[members] = True
    return combos, null


def fit_output_error(
    model: Any,
    datas: list[FlightData],
    names: list[str],
    initial: Mapping[str, float],
    *,
    outputs: list[str],
    x0: list[dict[str, float]],
    estimate_x0: list[str],
    estimate_bias: list[str],
    weights: FloatArray | None,
    error_bars: str,
    max_iterations: int,
    tolerance: float,
    simulate_options: Mapping[str, Any],
    gradient: str,
) -> IdentificationResult:
    """Run the estimation; arguments are already validated by `identify`."""
    all_out = list(model.outputs)
    out_idx = [all_out.index(o) for o in outputs]
    states = list(getattr(model, "states", ()))
    state_out = [outputs.index(s) if s in outputs else -1 for s in states]
    n_y = len(outputs)
    mans: list[_Manoeuvre] = []
    for d, x in zip(datas, x0, strict=True):
        x_arr = np.array([float(x.get(s, 0.0)) for s in states])
        mans.append(
            _Manoeuvre(
                data=d,
                time=d.time,
                controls=d.array(list(model.controls)),
                measured=d.array(outputs),
                x0=x_arr,
                x0_free=[states.index(s) for s in estimate_x0],
                bias=np.zeros(n_y),
                bias_free=[outputs.index(o) for o in estimate_bias],
            )
        )
    n_p = len(names)
    pos = n_p
    x0_slices, bias_slices = [], []
    for m in mans:
        x0_slices.append(slice(pos, pos + len(m.x0_free)))
        pos += len(m.x0_free)
    for m in mans:
        bias_slices.append(slice(pos, pos + len(m.bias_free)))
        pos += len(m.bias_free)
    layout = _Layout(names, n_p, x0_slices, bias_slices, pos)
    theta = np.zeros(pos)
    theta[:n_p] = [initial[n] for n in names]
    for i, m in enumerate(mans):
        theta[x0_slices[i]] = m.x0[m.x0_free]
    fixed = {k: float(v) for k, v in model.parameters.items() if k not in names}
    problem = _Problem(model, mans, layout, out_idx, fixed, simulate_options, gradient)
    typ = _typical_scales(layout, theta, mans, state_out)
    all_meas = np.concatenate([m.measured for m in mans], axis=0)
    floor = 1e-14 * np.maximum(np.mean(all_meas**2, axis=0), 1e-300)
    names_all = list(names)
    for i, m in enumerate(mans):
        names_all += [f"x0[{i}].{states[s]}" for s in m.x0_free]
    for i, m in enumerate(mans):
        names_all += [f"bias[{i}].{outputs[k]}" for k in m.bias_free]

    # Stepped simulators integrate to a tolerance of their own (often ~1e-9), so
    # their differences need steps near the square root of it.
    rel = 1e-6 if hasattr(model, "simulate_batch") else 1e-4

    def steps_for(th: FloatArray) -> FloatArray:
        return rel * np.maximum(np.abs(th), typ)

    residuals, first_jac, ok = problem.evaluate(theta, steps_for(theta))
    if not ok or first_jac is None:
        raised = f" (its simulate raised {problem.errors[0]})" if problem.errors else ""
        raise IdentificationError(
            f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
            f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))}{raised}; "
            "check the initial guesses and the model"
        )
    jacobians: list[FloatArray] = first_jac
    fixed_r = None if weights is None else np.asarray(weights, dtype=np.float64)
    cost = _ml_cost(residuals, fixed_r, floor)
    if not np.isfinite(cost):
        # Squares of values near 1e155 and beyond overflow float64: no step can be judged.
        with np.errstate(over="ignore", invalid="ignore"):
            mean_sq = np.mean(np.concatenate(residuals, axis=0) ** 2, axis=0)
        overflow = [o for o, v in zip(outputs, mean_sq, strict=True) if not np.isfinite(v)]
        peak = float(np.max(np.abs(all_meas)))
        raise IdentificationError(
            f"the fit cost is not finite at the initial parameters (cost {cost}): the "
            f"squared residuals of outputs {overflow or outputs} overflow (measured values up "
            f"to {peak:.3g}); check the data's units and scale"
        )
    success = False
    message = f"iteration limit ({max_iterations}) reached before convergence"
    lam = 0.0
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        r = fixed_r if fixed_r is not None else _noise_variances(residuals, floor)
        info = _information(jacobians, r)
        grad = _gradient(jacobians, residuals, r)
        dn = np.sqrt(np.clip(np.diag(info), 1e-300, None))
        a = info / np.outer(dn, dn)
        b = grad / dn
        accepted = False
        for _attempt in range(12):
            try:
                step = np.linalg.lstsq(a + lam * np.eye(a.shape[0]), b, rcond=1e-12)[0] / dn
            except np.linalg.LinAlgError:
                step = np.zeros_like(theta)
            # Gauss–Newton minimises sum v'R^-1 v, so the step *adds* the solution
            # of M step = -J'R^-1 v with J the residual Jacobian (J = -dy/dtheta).
            trial = theta - step
            t_res, t_jac, t_ok = problem.evaluate(trial, steps_for(trial))
            if t_ok and t_jac is not None:
                t_cost = _ml_cost(t_res, fixed_r, floor)
                if t_cost <= cost + 1e-12 * abs(cost):
                    accepted = True
                    break
            lam = max(lam * 10.0, 1e-4)
        if not accepted:
            success = True
            message = "converged (no further decrease possible)"
            break
        rel_step = float(np.max(np.abs(step) / np.maximum(np.abs(theta), typ)))
        dcost = cost - t_cost
        assert t_jac is not None  # accepted trials always carry their Jacobian
        theta, residuals, jacobians, cost = trial, t_res, t_jac, t_cost
        lam = lam / 10.0 if lam > 1e-6 else 0.0
        if rel_step < tolerance or dcost < tolerance * max(1.0, abs(cost)) * 1e-3:
            success = True
            message = f"converged after {iteration} iterations"
            break
    r = fixed_r if fixed_r is not None else _noise_variances(residuals, floor)
    info = _information(jacobians, r)
    combos, null = _combinations(info, names_all)
    identifiable = not combos
    try:
        m_inv: FloatArray = np.asarray(
            np.linalg.pinv(info, rcond=1e-13, hermitian=True), dtype=np.float64
        )
    except np.linalg.LinAlgError:
        m_inv = np.full_like(info, np.nan)
    cov_white: FloatArray = m_inv.copy()
    shown = error_bars
    tau = max(_bandwidth(v)[1] for v in residuals)
    if error_bars == "colored" and tau <= _WHITE_TAU:
        # Residuals indistinguishable from white: the classical bound is the right
        # one, and a lag-window estimate would only add noise to it.
        shown = "white"
    if shown == "colored":
        cov_col = _colored_covariance(jacobians, residuals, r, m_inv)
        cov = cov_col
        dc = np.diag(cov_col)
        bad = ~(dc > 0)
        if np.any(bad):  # degenerate estimate: fall back to the classical one
            cov[bad, :] = cov_white[bad, :]
            cov[:, bad] = cov_white[:, bad]
    else:
        cov = cov_white
    if not identifiable:
        for j in np.flatnonzero(null):
            cov[j, :] = np.nan
            cov[:, j] = np.nan
            cov[j, j] = np.inf
            cov_white[j, :] = np.nan
            cov_white[:, j] = np.nan
            cov_white[j, j] = np.inf
        text = "; ".join(" + ".join(c) for c in combos)
        warnings.warn(
            f"the data cannot separate these parameter combinations: {text}; their "
            "standard errors are reported as infinite",
            IdentifiabilityWarning,
            stacklevel=3,
        )
    if not success:
        warnings.warn(
            f"identify: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=3,
        )
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    se[~np.isfinite(np.diag(cov))] = np.inf
    x0_out = []
    bias_out = []
    for i, m in enumerate(mans):
        xi, bi = problem.unpack(theta, i)
        x0_out.append({s: float(xi[j]) for j, s in enumerate(states)})
        bias_out.append({outputs[k]: float(bi[k]) for k in m.bias_free})
    extra = {names_all[j]: float(se[j]) for j in range(n_p, layout.n_total)}
    return IdentificationResult(
        parameters={n: float(theta[j]) for j, n in enumerate(names)},
        stderr={n: float(se[j]) for j, n in enumerate(names)},
        covariance=cov[:n_p, :n_p],
        parameter_names=tuple(names),
        fixed=fixed,
        covariance_white=cov_white[:n_p, :n_p],
        error_bars=shown,
        identifiable=identifiable,
        unidentifiable=tuple(combos),
        success=success,
        message=message,
        n_iterations=iteration,
        cost=cost,
        method="output_error",
        output_names=tuple(outputs),
        noise_covariance=np.diag(r),
        initial_states=tuple(x0_out),
        biases=tuple(bias_out),
        extra_stderr=extra,
        residuals=tuple(residuals),
        model_name=str(getattr(model, "name", "")),
    )
