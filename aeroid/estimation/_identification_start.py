"""Starting values of an identification: parameter and initial-state names with their first
guesses, the initial states of each manoeuvre, and the equation-error start.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._value_checks import check_distinct
from ..errors import IdentificationError
from ..io.data import FlightData, as_float, plain

FloatArray = NDArray[np.float64]


def _as_list(data: Any) -> list[FlightData]:
    if isinstance(data, FlightData):
        return [data]
    if isinstance(data, (list, tuple)) and data and all(isinstance(d, FlightData) for d in data):
        return list(data)
    raise IdentificationError(
        f"data: expected FlightData or a non-empty list of FlightData, got {type(data).__name__}"
    )


def names_and_initial(
    model: Any, parameters: Any, *, allow_empty: bool = False
) -> tuple[list[str], dict[str, float]]:
    """The names to estimate and their initial guesses; none only with `allow_empty`
    (a caller that estimates initial states, biases or delays besides checks it)."""
    nominal = dict(model.parameters)
    if isinstance(parameters, str):
        parameters = [parameters]
    if isinstance(parameters, Mapping):
        names = list(parameters)
        initial = {}
        for n, v in parameters.items():
            value = as_float(v)
            if value is None:
                raise IdentificationError(
                    f"parameters: initial guess of {n!r} is not a number: {plain(v)}"
                )
            initial[n] = value
    else:
        try:
            names = [str(n) for n in parameters]
        except TypeError:
            raise IdentificationError(
                "parameters: expected a list of names to estimate or a dict name -> initial guess"
            ) from None
        initial = {}
    if not names and not allow_empty:
        raise IdentificationError("parameters: name at least one parameter to estimate")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise IdentificationError(f"parameters: listed twice: {dupes}")
    for n in names:
        if n not in nominal:
            raise IdentificationError(
                f"parameter {n!r} is not a parameter of model {model.name!r}; "
                f"its parameters are {sorted(nominal)}"
            )
        initial.setdefault(n, float(nominal[n]))
        if not np.isfinite(initial[n]):
            raise IdentificationError(f"parameters: initial guess of {n!r} is not finite")
    return names, initial


def _select(option: Any, available: Sequence[str], what: str, *, strict: bool = True) -> list[str]:
    if option is False or option is None:
        return []
    if option is True:
        return list(available)
    try:
        chosen = [option] if isinstance(option, str) else list(option)
    except TypeError:
        raise IdentificationError(
            f"{what}: expected True, False or a list of names, got {plain(option)}"
        ) from None
    for c in chosen:
        if c not in available and strict:
            raise IdentificationError(f"{what}: {c!r} is not one of {list(available)}")
    check_distinct(chosen, what, IdentificationError)
    return [c for c in chosen if c in available]


def _x0_values(xi: Any, states: list[str]) -> dict[str, float]:
    """One manoeuvre's given initial state (mapping or array) by state name."""
    if isinstance(xi, Mapping):
        unknown = sorted(set(xi) - set(states))
        if unknown:
            raise IdentificationError(f"x0: unknown states {unknown}; states: {states}")
        out = {}
        for s, v in xi.items():
            try:
                out[s] = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(f"x0[{s!r}]: expected a number, got {plain(v)}") from None
    else:
        try:
            arr = np.asarray(xi, dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise IdentificationError(
                f"x0: expected a mapping of state -> value or {len(states)} numbers for "
                f"states {states}, got {plain(xi)}"
            ) from None
        if arr.size != len(states):
            raise IdentificationError(
                f"x0: expected {len(states)} values for states {states}, got {arr.size}"
            )
        out = dict(zip(states, arr.tolist(), strict=True))
    bad = [s for s, v in out.items() if not np.isfinite(v)]
    if bad:
        raise IdentificationError(f"x0: the initial value of {bad} is not finite")
    return out


def _equation_error_start(
    model: Any,
    datas: list[FlightData],
    names: list[str],
    initial: Mapping[str, float],
    delays: Mapping[str, float],
    box: Mapping[str, tuple[float, float]],
) -> dict[str, float]:
    """Start values from an equation-error regression of the state equations (see
    `identify`, ``start="equation_error"``)."""
    from ..errors import ChannelError
    from ..io.smoothing import differentiate
    from ..models.integration import shifted_controls

    if not hasattr(model, "dynamics") or not hasattr(model, "_dynamics_batch"):
        raise IdentificationError(
            "start='equation_error' regresses the state equations, so it needs a Model with a "
            "dynamics callable (not a stepped simulator)"
        )
    states = list(model.states)
    controls = list(model.controls)
    for i, d in enumerate(datas):
        missing = [s for s in states if s not in d]
        if missing:
            raise ChannelError(
                f"start='equation_error' needs every state measured; states {missing} are not "
                f"channels of data[{i}] (channels: {sorted(d.channels)})"
            )
    n_x, n_p = len(states), len(names)
    base = {k: float(v) for k, v in model.parameters.items()}
    base.update({n: float(initial[n]) for n in names})
    scale = np.array([max(abs(base[n]), 1.0) for n in names])
    # Members: the start, one unit step (in `scale`) per parameter, a step back per
    # parameter and one joint step; a model linear in the parameters reproduces the
    # last n_p + 1 from the first n_p + 1.
    coef = np.zeros((2 * n_p + 2, n_p))
    coef[1 : n_p + 1] = np.eye(n_p)
    coef[n_p + 1 : 2 * n_p + 1] = -np.eye(n_p)
    coef[-1] = np.linspace(-0.7, 1.3, n_p) if n_p > 1 else 0.6
    members = coef.shape[0]
    rows: list[FloatArray] = []
    cols: list[FloatArray] = []
    for i, d in enumerate(datas):
        n_t = d.n_samples
        x = d.array(states)
        u = d.array(controls) if controls else np.zeros((n_t, 0))
        if delays:
            u = shifted_controls(
                d.time, u, [controls.index(c) for c in delays], list(delays.values())
            )
        given = [s for s in states if f"{s}_dot" in d]
        xdot = np.empty((n_t, n_x))
        if len(given) < n_x:
            dt = float(np.mean(np.diff(d.time)))
            xdot[:] = np.asarray(differentiate(x, dt=dt), dtype=np.float64).reshape(n_t, n_x)
        for s in given:  # measured derivatives (e.g. angular accelerations) win
            xdot[:, states.index(s)] = d[f"{s}_dot"]
        P = {k: np.full(members * n_t, v) for k, v in base.items()}
        for j, n in enumerate(names):
            P[n] = np.repeat(base[n] + coef[:, j] * scale[j], n_t)
        T = np.tile(d.time, members)
        X = np.ascontiguousarray(np.tile(x.T, members))
        U = np.ascontiguousarray(np.tile(u.T, members))
        try:
            with np.errstate(all="ignore"):
                F = model._dynamics_batch.at_times(T, X, U, P)
        except Exception as exc:
            raise IdentificationError(
                f"start='equation_error': the dynamics of model {model.name!r} failed on the "
                f"measured states of data[{i}]: {type(exc).__name__}: {exc}"
            ) from None
        F = np.asarray(F, dtype=np.float64).reshape(n_x, members, n_t)
        f0 = F[:, 0]
        c = F[:, 1 : n_p + 1] - f0[:, None]  # (n_x, n_p, n_t): df/dp times the scale
        pred_back = f0[:, None] - c
        pred_joint = f0 + np.einsum("j,kjt->kt", coef[-1], c)
        size = max(float(np.max(np.abs(F))) if np.all(np.isfinite(F)) else np.inf, 1e-300)
        tol = 1e-7 * size
        with np.errstate(all="ignore"):
            off_back = np.max(np.abs(F[:, n_p + 1 : 2 * n_p + 1] - pred_back), axis=(0, 2))
            off_joint = float(np.max(np.abs(F[:, -1] - pred_joint)))
        bad = [n for n, e in zip(names, off_back, strict=True) if not e <= tol]
        if bad or not off_joint <= tol:
            which = f"parameters {bad}" if bad else f"the parameters {names} jointly"
            raise IdentificationError(
                f"start='equation_error' needs dynamics linear in the estimated parameters; "
                f"the dynamics of model {model.name!r} are not linear in {which}; give start "
                "values instead (start='given')"
            )
        z = xdot.T - f0  # (n_x, n_t)
        for k in range(n_x):
            rows.append(z[k])
            cols.append(c[k].T)
    # Equations in their own units: each weighted by its response's spread, so no
    # state's units dominate the stacked regression.
    weights = [1.0 / max(float(np.std(r)), 1e-300) for r in rows]
    a = np.concatenate([w * cc for w, cc in zip(weights, cols, strict=True)], axis=0)
    b = np.concatenate([w * r for w, r in zip(weights, rows, strict=True)])
    norms = np.linalg.norm(a, axis=0)
    live = np.flatnonzero(norms > 1e-12 * max(float(np.max(norms, initial=0.0)), 1e-300))
    out = dict(initial)
    if not live.size:
        return out
    from scipy.linalg import qr

    an = a[:, live] / norms[live]
    _q, r_mat, piv = qr(an, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r_mat))
    # columns the regression separates from the ones before them (pivoted QR)
    keep = live[np.sort(piv[diag > 1e-6 * diag[0]])]
    sol = np.linalg.lstsq(a[:, keep], b, rcond=None)[0]
    for j, step in zip(keep.tolist(), sol.tolist(), strict=True):
        n = names[j]
        value = base[n] + step * scale[j]
        if np.isfinite(value):
            lo, hi = box.get(n, (-np.inf, np.inf))
            out[n] = float(np.clip(value, lo, hi))
    return out


def _is_state_entry(entry: Any) -> bool:
    """True for what can only be one manoeuvre's whole initial state (not a number)."""
    return entry is None or isinstance(entry, Mapping) or np.ndim(entry) >= 1


def _x0_per_manoeuvre(x0: Any, n_man: int, states: list[str]) -> list[Any]:
    """One initial-state specification per manoeuvre from `x0` (see `identify`)."""
    if isinstance(x0, np.ndarray) and x0.ndim == 2 and x0.shape[0] == n_man:
        return list(x0)
    if isinstance(x0, np.ndarray) and x0.ndim == 1:
        x0 = x0.tolist()
    if not isinstance(x0, (list, tuple)) or not x0:
        return [x0] * n_man
    entries = list(x0)
    if all(_is_state_entry(e) for e in entries):
        if len(entries) == n_man:
            return entries
        if all(isinstance(e, Mapping) or e is None for e in entries):
            raise IdentificationError(
                f"x0: got a list of {len(entries)} initial states for {n_man} manoeuvre(s); "
                "give one per manoeuvre, or one mapping or state vector for all"
            )
        return [x0] * n_man
    if any(_is_state_entry(e) for e in entries):
        return [x0] * n_man  # a mixture: reported as a bad state vector below
    # A flat list of numbers: one state vector shared by every manoeuvre.
    if len(entries) == len(states):
        return [x0] * n_man
    if len(states) == 1 and len(entries) == n_man:
        return [[e] for e in entries]
    per = f", or a list of {n_man} initial states (one per manoeuvre)" if n_man > 1 else ""
    raise IdentificationError(
        f"x0: got {len(entries)} numbers; expected {len(states)} values for states {states} "
        f"(read as one initial state for every manoeuvre){per}"
    )


def _window_variances(
    e: FloatArray, n_windows: Sequence[int]
) -> tuple[FloatArray, list[FloatArray]]:
    """Mean square of the one-sample residuals `e` (n, n_x) and of their sums over
    every run of L consecutive samples, for each L of `n_windows`."""
    c = np.vstack([np.zeros((1, e.shape[1])), np.cumsum(e, axis=0)])
    return np.mean(e * e, axis=0), [np.mean((c[L:] - c[:-L]) ** 2, axis=0) for L in n_windows]


def process_noise_start(
    model: Any,
    datas: Sequence[FlightData],
    parameters: Mapping[str, float],
    measurement_noise: Mapping[str, float],
    states: Sequence[int],
) -> dict[int, float]:
    """Process-noise intensities (state² per second) to start a filter-error fit from:
    what the state equations at `parameters` leave unexplained in the measured states,
    less the measurement noise's share (see `aeroid.estimation._filter_error`).

    Over a window of L samples the trapezoidal residual of the state equations on the
    measured states sums to ``integral(w) + v(t + L dt) - v(t)`` plus the measurement
    noise that the state equations pass on: its mean square ``D(L)`` grows as
    ``2 R + L dt (Qc + dt J² R)``, with J the state equations' Jacobian. The slope between
    one sample and L samples gives Qc, free of the measurement noise R; the window whose
    estimate has the smallest relative standard error (about ``sqrt(2 L / n) D(L)`` over
    the slope's rise, n samples) is taken, records pooled by inverse variance. A state
    whose noise no window detects starts at the smallest intensity the record could
    show (one standard error). A record that does not measure every state, and a model
    whose equations fail on the measured states, give no start (the result leaves the
    states out).
    """
    names = list(model.states)
    controls = list(model.controls)
    sums: dict[int, list[float]] = {i: [0.0, 0.0] for i in states}  # sum w q, sum w
    floor: dict[int, float] = {}
    for d in datas:
        if d.n_samples < 16 or not all(s in d for s in names):
            continue  # the state equations need every state measured
        x = d.array(names)
        u = d.array(controls) if controls else np.zeros((d.n_samples, 0))
        n_t, n_x = x.shape
        t = np.asarray(d.time, dtype=np.float64)
        dt = float(np.median(np.diff(t)))
        # the measured record and, after it, one step in each state at the mean
        mean_x, mean_u = np.mean(x, axis=0), np.mean(u, axis=0)
        h = 1e-6 * np.maximum(np.abs(mean_x), 1e-3)
        X = np.hstack([x.T, np.repeat(mean_x[:, None], n_x + 1, axis=1)])
        X[np.arange(n_x), n_t + 1 + np.arange(n_x)] += h
        U = np.hstack([u.T, np.repeat(mean_u[:, None], n_x + 1, axis=1)])
        T = np.concatenate([t, np.full(n_x + 1, t[0])])
        P = {k: np.full(T.size, float(v)) for k, v in parameters.items()}
        try:
            with np.errstate(all="ignore"):
                F = np.asarray(model._dynamics_batch.at_times(T, X, U, P), dtype=np.float64)
        except Exception:
            return {}  # the fit's own checks name the failure
        F = F.reshape(n_x, T.size)
        if not np.all(np.isfinite(F)):
            continue
        J = (F[:, n_t + 1 :] - F[:, n_t : n_t + 1]) / h[None, :]
        # a state measured outside the outputs: white noise dominates its first differences
        half = 0.5 * np.var(np.diff(x, axis=0), axis=0)
        var = np.array([measurement_noise.get(s, half[j]) for j, s in enumerate(names)])
        share = dt * (J * J) @ var
        e = np.diff(x, axis=0) - 0.5 * np.diff(t)[:, None] * (F[:, 1:n_t] + F[:, : n_t - 1]).T
        windows = [2**k for k in range(1, 32) if 2**k <= n_t // 8]
        d1, dl = _window_variances(e, windows)
        for i in states:
            best, best_rel, lowest = math.nan, math.inf, math.inf
            for L, dL in zip(windows, dl, strict=True):
                rise = (L - 1) * dt
                spread = math.sqrt(2.0 * L / n_t) * float(dL[i]) / rise  # the slope's se
                q = (float(dL[i]) - float(d1[i])) / rise - float(share[i])
                lowest = min(lowest, spread)
                if q > 0 and spread / q < best_rel:
                    best, best_rel = q, spread / q
            if math.isfinite(best):
                w = 1.0 / (best * best_rel) ** 2
                sums[i][0] += w * best
                sums[i][1] += w
            elif math.isfinite(lowest) and lowest > 0:
                floor[i] = min(floor.get(i, math.inf), lowest)
    out: dict[int, float] = {}
    for i in states:
        total, weight = sums[i]
        if weight > 0:
            out[i] = total / weight
        elif i in floor:
            out[i] = floor[i]
    return out
