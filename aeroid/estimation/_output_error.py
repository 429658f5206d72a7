"""Maximum-likelihood output-error estimation: Gauss–Newton, damped by
Levenberg–Marquardt where a step fails, through `aeroid.estimation.least_squares.minimise`.

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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._linalg import information_inverse
from ..errors import (
    IdentifiabilityWarning,
    IdentificationError,
    SimulationError,
)
from ..io.data import FlightData
from ..models.integration import (
    Interpolation,
    check_control_interpolation,
    shifted_controls,
)
from ..models.model import simulator_problem
from ._excitation import refuse_runaway as _refuse_runaway
from ._identification_record import IdentificationResult
from ._noise_model import _bandwidth, _colored_covariance, _warn_unabsorbed_drift
from .identifiability import unidentifiable as _combinations
from .least_squares import Linearisation, minimise

FloatArray = NDArray[np.float64]

# Residuals count as coloured when a lag-one correlation is significant (3/sqrt(N)),
# which makes the estimated correlation time exceed 1.
_WHITE_TAU = 1.0
# the information's pseudo-inverse cut, on its unit-diagonal form (`information_inverse`)
_INFO_RCOND = 1e-13


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
    # Input time delays (s) sit right after the model parameters, at n_p + i: one
    # per delayed control (its column in the controls array).
    delayed: tuple[int, ...] = ()

    @property
    def n_d(self) -> int:
        return len(self.delayed)


def delay_parameter(control: str) -> str:
    """The name under which the time delay of `control` is reported."""
    return f"tau_{control}"


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


# outputs smaller than this cannot be weighted: their variances underflow
_TINY = 1e-140


def _overflow(outputs: Any, mean_sq: FloatArray, measured: FloatArray, cost: Any) -> None:
    """Raise the error of a fit whose squared residuals overflow, naming the outputs."""
    overflow = [o for o, v in zip(outputs, mean_sq, strict=True) if not np.isfinite(v)]
    peak = float(np.max(np.abs(measured)))
    raise IdentificationError(
        f"the fit cost is not finite at the initial parameters (cost {cost}): the "
        f"squared residuals of outputs {overflow or list(outputs)} overflow (measured values "
        f"up to {peak:.3g}); check the data's units and scale"
    )


def _simulate_members(
    model: Any,
    man: _Manoeuvre,
    params: Mapping[str, FloatArray],
    x0: FloatArray,
    out_idx: list[int],
    options: Mapping[str, Any],
    errors: list[str] | None = None,
    controls: FloatArray | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Outputs (B, n_t, n_y) and ok mask for a batch of parameter/x0 members; what a
    stepped simulator raised is appended to `errors`. `controls` (n_t, n_u) or per
    member (B, n_t, n_u) replaces the manoeuvre's measured controls."""
    u_all = man.controls if controls is None else controls
    if hasattr(model, "simulate_batch"):
        sim = model.simulate_batch(man.time, u_all, x0, params, **options)
        if errors is not None and not sim.ok[0] and sim.failure[0]:
            errors.append(sim.failure[0])
        return sim.outputs[:, :, out_idx], sim.ok
    # A stepped simulator: one run per member.
    batch = x0.shape[0]
    outs = np.full((batch, man.time.size, len(out_idx)), np.nan)
    ok = np.zeros(batch, dtype=bool)
    for b in range(batch):
        u_b = u_all[b] if u_all.ndim == 3 else u_all
        ctrl = {c: u_b[:, j] for j, c in enumerate(model.controls)}
        p = {k: float(v[b]) for k, v in params.items()}
        try:
            res = model.simulate(man.time, ctrl, None, p, **options)
        except Exception as exc:  # a failed member is a rejected point, not a crash
            if errors is not None:
                errors.append(f"its simulate raised {type(exc).__name__}: {exc}")
            continue
        problem = simulator_problem(model, res, man.time.size)
        if problem is None:
            outs[b] = np.asarray(res.outputs, dtype=np.float64)[:, out_idx]
            ok[b] = True
        elif errors is not None:
            errors.append(problem)
    return outs, ok


class _StartFailure(SimulationError, IdentificationError):
    """The model gives non-finite values at the initial parameters: a `SimulationError`
    like every such failure, and the `IdentificationError` that identify raises for a bad start."""


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
        self.interpolation: Interpolation = check_control_interpolation(
            self.options.get("control_interpolation", "linear"),
            IdentificationError,
            "simulate_options['control_interpolation']",
            getattr(model, "controls", None),
        )

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
            delays = theta[lay.n_p : lay.n_p + lay.n_d]
            u_now = shifted_controls(m.time, m.controls, lay.delayed, delays, self.interpolation)
            # simulated columns: model parameters and this manoeuvre's initial states
            cols = list(range(lay.n_p)) + list(range(sx.start, sx.stop))
            # gradient="auto": the exact sensitivities of the compiled RK4 when
            # the model compiles and integrates by RK4 (decided at the first call).
            route = getattr(self, "_compiled_route", None)
            sens = None
            p = dict(self.fixed)
            p.update({n: float(theta[j]) for j, n in enumerate(lay.names)})
            if steps is not None and self.gradient == "auto" and route in (None, True):
                from ..models import compiled as _compiled

                sens = _compiled.output_sensitivities(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    m.x0_free,
                    self.options,
                    probe=route is None,
                    numpy_first=route is None,
                )
                if sens is None:
                    # a first fit that compiling would not pay for runs in numpy, with
                    # the sensitivities of Newton's method over the record (`_shooting`,
                    # straight lines only: the cubic's are central differences)
                    numpy = _compiled.declined(self.model) and self.interpolation == "linear"
                    route = "numpy" if numpy else False
                    self._compiled_route = route
            if steps is not None and route == "numpy":
                from ..models import compiled as _compiled
                from ..models import shooting as _shooting

                sens = _shooting.output_sensitivities(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    m.x0_free,
                    _compiled.rk4_substeps(self.model, m.time, u_now, x0, p, self.options),
                    steps[cols],
                )
                if sens is None and self.model._dynamics_batch.time_broadcasts is False:
                    # dynamics that do not take an array of times: step by step from now
                    # on (a point where Newton did not settle steps once, below)
                    self._compiled_route = False
            if (
                steps is not None
                and sens is not None
                and np.all(np.isfinite(sens[0]))
                and np.all(np.isfinite(sens[1]))
            ):
                # (a diverging point falls through to the numpy path, which reports it)
                y_all, jac_all = sens
                y = y_all[:, self.out_idx]
                if route is None:
                    self._compiled_route = True
                v = m.measured - y - bias
                picked = jac_all[:, self.out_idx, :]
                if len(cols) == lay.n_total:  # one manoeuvre, no delays or biases
                    jac = np.negative(picked, out=picked)
                else:
                    jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                    jac[:, :, cols] = -picked
                if not self._append(residuals, jacobians, v, jac, (theta, steps, i, x0)):
                    return [], None, False
                continue
            if steps is not None and self.gradient == "jax":
                from ..models import jax_compiled as _jax

                y, jac_p = _jax.outputs_and_jacobian(
                    self.model,
                    m.time,
                    u_now,
                    x0,
                    p,
                    lay.names,
                    substeps=self.options.get("substeps"),
                    control_interpolation=self.interpolation,
                )
                y = np.asarray(y)[:, self.out_idx]
                jac_p = np.asarray(jac_p)[:, self.out_idx, :]
                if not np.all(np.isfinite(y)):
                    return [], None, False
                v = m.measured - y - bias
                jac = np.zeros((m.time.size, len(self.out_idx), lay.n_total))
                jac[:, :, : lay.n_p] = -jac_p
                if not self._append(residuals, jacobians, v, jac, (theta, steps, i, x0)):
                    return [], None, False
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
                self.model, m, P, X0, self.out_idx, self.options, self.errors, u_now
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
                if not self._delay_columns(jac, theta, steps, i, x0):
                    return [], None, False
                self._bias_columns(jac, i)
                assert jacobians is not None
                jacobians.append(jac)
        return residuals, jacobians, True

    def _append(
        self,
        residuals: list[FloatArray],
        jacobians: list[FloatArray] | None,
        v: FloatArray,
        jac: FloatArray,
        at: tuple[FloatArray, FloatArray, int, FloatArray],
    ) -> bool:
        """Complete manoeuvre i's Jacobian (delay and bias columns; `at` is theta, the
        steps, i and x0) and keep it with its residuals; False where a delay's
        difference fails."""
        theta, steps, i, x0 = at
        if not self._delay_columns(jac, theta, steps, i, x0):
            return False
        residuals.append(v)
        self._bias_columns(jac, i)
        assert jacobians is not None
        jacobians.append(jac)
        return True

    def _delay_columns(
        self, jac: FloatArray, theta: FloatArray, steps: FloatArray, i: int, x0: FloatArray
    ) -> bool:
        """Fill the time-delay columns of manoeuvre i's Jacobian by central differences
        of the delayed controls (``-du/dt dy/du``, exact within a sample interval,
        where the interpolated control is linear in the delay); False when a member
        fails."""
        lay = self.layout
        if not lay.n_d:
            return True
        m = self.mans[i]
        base = theta[lay.n_p : lay.n_p + lay.n_d]
        batch = 2 * lay.n_d
        U = np.empty((batch, *m.controls.shape))
        for c in range(lay.n_d):
            for sign, b in ((1.0, 2 * c), (-1.0, 2 * c + 1)):
                d = base.copy()
                d[c] += sign * steps[lay.n_p + c]
                U[b] = shifted_controls(m.time, m.controls, lay.delayed, d, self.interpolation)
        P = {n: np.full(batch, theta[j]) for j, n in enumerate(lay.names)}
        X0 = np.repeat(x0[None, :], batch, axis=0)
        outs, ok = _simulate_members(self.model, m, P, X0, self.out_idx, self.options, None, U)
        if not np.all(ok):
            return False
        for c in range(lay.n_d):
            h = steps[lay.n_p + c]
            jac[:, :, lay.n_p + c] = -(outs[2 * c] - outs[2 * c + 1]) / (2 * h)
        return True

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
        with np.errstate(over="ignore", invalid="ignore"):  # overflowed: said below
            m += flat.T @ flat
    return m


def _gradient(
    jacobians: list[FloatArray], residuals: list[FloatArray], r: FloatArray
) -> FloatArray:
    g = np.zeros(jacobians[0].shape[2])
    for jac, v in zip(jacobians, residuals, strict=True):
        g += np.einsum("tkp,tk->p", jac, v / r[None, :])
    return g


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
    bounds: Mapping[str, tuple[float, float]] | None = None,
    delays: Mapping[str, float] | None = None,
) -> IdentificationResult:
    """Run the estimation; arguments are already validated by `identify`.

    `delays` (control name -> start value in s) adds one pure time delay per
    named control to the unknowns: the control is simulated as its samples
    delayed, ``u(t_k - tau)`` on the data grid (`shifted_controls`), so every simulation path, the LTI and compiled ones
    included, stays valid, and its sensitivity is a central difference in
    tau. The delays are reported as parameters ``tau_<control>``.

    With `bounds` (name -> (lower, upper), ±inf for an open side) the
    Gauss–Newton steps are projected: a parameter at a bound whose step would
    leave the box is held there and dropped from that step's normal equations
    (the active set, as in Jategaonkar's bounded Gauss–Newton), and the rest of
    the step is clipped into the box, so every iterate is feasible. Parameters
    that end at a bound are reported in ``active_bounds``; the covariance is
    computed with them held fixed (their rows and columns zero).
    """
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
    delay_controls = list(delays or {})
    n_d = len(delay_controls)
    controls = list(model.controls)
    delayed = tuple(controls.index(c) for c in delay_controls)
    pos = n_p + n_d
    x0_slices, bias_slices = [], []
    for m in mans:
        x0_slices.append(slice(pos, pos + len(m.x0_free)))
        pos += len(m.x0_free)
    for m in mans:
        bias_slices.append(slice(pos, pos + len(m.bias_free)))
        pos += len(m.bias_free)
    layout = _Layout(names, n_p, x0_slices, bias_slices, pos, delayed)
    theta = np.zeros(pos)
    theta[:n_p] = [initial[n] for n in names]
    theta[n_p : n_p + n_d] = [float((delays or {})[c]) for c in delay_controls]
    for i, m in enumerate(mans):
        theta[x0_slices[i]] = m.x0[m.x0_free]
    box = dict(bounds or {})
    lower = np.full(pos, -np.inf)
    upper = np.full(pos, np.inf)
    for jb, n in enumerate(names):
        lower[jb], upper[jb] = box.get(n, (-np.inf, np.inf))
    theta = np.clip(theta, lower, upper)  # identify checked the start; this is a no-op there
    fixed = {k: float(v) for k, v in model.parameters.items() if k not in names}
    problem = _Problem(model, mans, layout, out_idx, fixed, simulate_options, gradient)
    all_meas = np.concatenate([m.measured for m in mans], axis=0)
    with np.errstate(over="ignore", invalid="ignore"):
        meas_sq = np.mean(all_meas**2, axis=0)
    if not np.all(np.isfinite(meas_sq)):
        # the scales of the steps (and any residual) would overflow: refuse before the
        # first simulation, naming the outputs
        _overflow(outputs, meas_sq, all_meas, "inf")
    with np.errstate(under="ignore"):
        peaks = np.max(np.abs(all_meas), axis=0)
    tiny = [o for o, top in zip(outputs, peaks, strict=True) if 0.0 < top < _TINY]
    if tiny:
        # their noise variances (squares of squares' means) underflow to zero
        raise IdentificationError(
            f"outputs {tiny}: values below {_TINY:g} in size, whose squares underflow "
            "float64; measure them in a smaller unit"
        )
    typ = _typical_scales(layout, theta, mans, state_out)
    if n_d:
        # a delay's natural scale is the sample interval
        typ[n_p : n_p + n_d] = min(float(np.min(np.diff(m.time))) for m in mans)
    floor = 1e-14 * np.maximum(meas_sq, 1e-300)
    delay_names = [delay_parameter(c) for c in delay_controls]
    names_all = list(names) + delay_names
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
        # states no record measures start at zero unless x0 says otherwise: a likely cause
        unseen = [
            s
            for j, s in enumerate(states)
            if all(s not in m.data.channels and m.x0[j] == 0.0 for m in mans)
        ]
        hint = (
            f"; the states {unseen} are in no record and start at zero (give x0 for them)"
            if unseen
            else ""
        )
        if problem.errors and hasattr(model, "simulate_batch"):
            raise _StartFailure(
                f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
                f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))}: "
                f"{problem.errors[0]}{hint}; check the initial guesses and the model"
            )
        if problem.errors:  # what the stepped simulator did, named (model, output, time)
            raise _StartFailure(
                f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
                f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))} "
                f"({problem.errors[0]}){hint}; check the initial guesses and the model"
            )
        raise IdentificationError(
            f"the model {getattr(model, 'name', '')!r} cannot be simulated at the initial "
            f"parameters {dict(zip(names, theta[:n_p].tolist(), strict=True))}{hint}; "
            "check the initial guesses and the model"
        )
    jacobians: list[FloatArray] = first_jac
    fixed_r = None if weights is None else np.asarray(weights, dtype=np.float64)
    cost = _ml_cost(residuals, fixed_r, floor)
    if not np.isfinite(cost):
        # Squares of values near 1e155 and beyond overflow float64: no step can be judged.
        with np.errstate(over="ignore", invalid="ignore"):
            mean_sq = np.mean(np.concatenate(residuals, axis=0) ** 2, axis=0)
        _overflow(outputs, mean_sq, all_meas, cost)

    def linearise(res: list[FloatArray], jacs: list[FloatArray], cost_here: float) -> Linearisation:
        # the noise variances re-estimated from these residuals weight the step
        r_here = fixed_r if fixed_r is not None else _noise_variances(res, floor)
        return Linearisation(
            cost_here, _gradient(jacs, res, r_here), _information(jacs, r_here), (res, jacs)
        )

    def evaluate(trial: FloatArray, _base: Linearisation | None) -> Linearisation | None:
        t_res, t_jac, t_ok = problem.evaluate(trial, steps_for(trial))
        if not t_ok or t_jac is None:
            return None
        return linearise(t_res, t_jac, _ml_cost(t_res, fixed_r, floor))

    fit = minimise(
        evaluate,
        theta,
        linearise(residuals, jacobians, cost),
        tolerance=tolerance,
        max_iterations=max_iterations,
        typical=typ,
        lower=lower,
        upper=upper,
    )
    theta, cost = fit.theta, fit.point.cost
    residuals, jacobians = fit.point.payload
    success, message, iteration = fit.success, fit.message, fit.iterations
    _refuse_runaway(model, names, theta[:n_p], outputs, residuals, all_meas)
    r = fixed_r if fixed_r is not None else _noise_variances(residuals, floor)
    info = _information(jacobians, r)
    held = np.zeros(layout.n_total, dtype=bool)
    held[:n_p] = (theta[:n_p] <= lower[:n_p]) | (theta[:n_p] >= upper[:n_p])
    keep = np.flatnonzero(~held)
    if np.any(held):
        # Error bars conditional on the active bounds: the held parameters leave the
        # information matrix (and the coloured-residual sandwich) as if fixed.
        jacobians = [jac[:, :, keep] for jac in jacobians]
        info = info[np.ix_(keep, keep)]
    combos, null = _combinations(info, [names_all[j] for j in keep])
    identifiable = not combos
    try:
        m_inv: FloatArray = information_inverse(info, rcond=_INFO_RCOND)
    except np.linalg.LinAlgError:
        m_inv = np.full_like(info, np.nan)
    cov_white: FloatArray = m_inv.copy()
    shown = error_bars
    tau = max(_bandwidth(v)[1] for v in residuals)
    if error_bars == "colored" and tau <= _WHITE_TAU:
        # Residuals indistinguishable from white: the classical bound is the right
        # one, and a lag-window estimate would only add noise to it.
        shown = "white"
    # classical degrees of freedom: observations less estimates
    n_obs = sum(int(v.size) for v in residuals)
    nu: FloatArray = np.full(keep.size, float(max(n_obs - keep.size, 1)))
    if shown == "colored" and not (np.all(np.isfinite(m_inv)) and np.all(np.isfinite(info))):
        shown = "white"  # no usable information (sensitivities overflowed): nothing to colour
    if shown == "colored":
        from .._colour import colored_covariance

        _, phi, _ = _colored_covariance(jacobians, residuals, r, m_inv)
        root = np.sqrt(r)
        cov_col, nu_kept = colored_covariance(
            [jac / root[None, :, None] for jac in jacobians],
            [v / root[None, :] for v in residuals],
            m_inv,
            estimated_weights=fixed_r is None,
            rcond=_INFO_RCOND,
        )
        # the spectrum behind the bars is itself estimated: its degrees of freedom
        # travel with the result, whose intervals take the t quantile
        nu = nu_kept
        with np.errstate(under="ignore"):
            spread = np.sqrt(np.mean(np.concatenate(residuals, axis=0) ** 2, axis=0))
        _warn_unabsorbed_drift(
            phi,
            mans,
            outputs,
            cov_col,
            cov_white,
            [names_all[j] for j in keep],
            states,
            jacobians,
            # a fit to rounding has no noise to drift: its residuals' correlation is
            # the integrator's, not the record's
            exact=set(np.flatnonzero(spread <= 1e-9 * np.sqrt(meas_sq)).tolist()),
        )
        cov = cov_col
        dc = np.diag(cov_col)
        bad = ~(dc > 0)
        if np.any(bad):  # degenerate estimate: fall back to the classical one
            cov[bad, :] = cov_white[bad, :]
            cov[:, bad] = cov_white[:, bad]
    else:
        cov = cov_white
    if np.any(held):  # back to every unknown: zero rows and columns for the held ones
        cov_full = np.zeros((layout.n_total, layout.n_total))
        cov_full[np.ix_(keep, keep)] = cov
        white_full = np.zeros_like(cov_full)
        white_full[np.ix_(keep, keep)] = cov_white
        null_full = np.zeros(layout.n_total, dtype=bool)
        null_full[keep] = null
        nu_full = np.full(layout.n_total, np.inf)
        nu_full[keep] = nu
        cov, cov_white, null, nu = cov_full, white_full, null_full, nu_full
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
            stacklevel=4,  # fit_output_error, identify, its BLAS wrapper, the caller
        )
    if not success:
        warnings.warn(
            f"identify: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=4,  # fit_output_error, identify, its BLAS wrapper, the caller
        )
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    se[~np.isfinite(np.diag(cov))] = np.inf
    x0_out = []
    bias_out = []
    for i, m in enumerate(mans):
        xi, bi = problem.unpack(theta, i)
        x0_out.append({s: float(xi[j]) for j, s in enumerate(states)})
        bias_out.append({outputs[k]: float(bi[k]) for k in m.bias_free})
    n_e = n_p + n_d  # model parameters, then time delays
    extra = {names_all[j]: float(se[j]) for j in range(n_e, layout.n_total)}
    return IdentificationResult(
        parameters={n: float(theta[j]) for j, n in enumerate(names_all[:n_e])},
        stderr={n: float(se[j]) for j, n in enumerate(names_all[:n_e])},
        covariance=cov[:n_e, :n_e],
        parameter_names=tuple(names_all[:n_e]),
        fixed=fixed,
        covariance_white=cov_white[:n_e, :n_e],
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
        full_covariance=cov,
        full_names=tuple(names_all),
        degrees_of_freedom={n: float(nu[j]) for j, n in enumerate(names_all)},
        residuals=tuple(residuals),
        model_name=str(getattr(model, "name", "")),
        bounds={n: box[n] for n in names if n in box},
        active_bounds={
            n: ("lower" if theta[j] <= lower[j] else "upper")
            for j, n in enumerate(names)
            if held[j]
        },
        time_delays={c: float(theta[n_p + i]) for i, c in enumerate(delay_controls)},
    )
