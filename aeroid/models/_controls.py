"""How a record's controls run between their samples: straight lines (the default
everywhere) or a C1 local cubic, and the controls at RK4's nodes (internal; re-exported
by `aeroid.models.integration`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AeroidError, SimulationError

FloatArray = NDArray[np.float64]

# How the controls run between their samples. "linear" (straight lines) is the
# default and what every path supports; "cubic" is the C1 local cubic of
# `control_slopes` (Catmull-Rom on a uniform grid), which the RK4 paths and the
# adaptive solvers take and the exact LTI discretisation and Euler refuse.
CONTROL_INTERPOLATIONS = ("linear", "cubic")

# one of CONTROL_INTERPOLATIONS for every control, or one per control column
Interpolation = str | tuple[str, ...]


def check_control_interpolation(
    value: Any,
    error: type[AeroidError] = SimulationError,
    name: str = "control_interpolation",
    controls: Sequence[str] | None = None,
) -> Interpolation:
    """`value` normalised: a name among `CONTROL_INTERPOLATIONS`, or, given the model's
    `controls`, a mapping of some of them to such names (the others straight) as one
    name per control column (one name when they agree); else `error` naming the fault."""
    if isinstance(value, str) and value in CONTROL_INTERPOLATIONS:
        return value
    if isinstance(value, tuple) and value and all(v in CONTROL_INTERPOLATIONS for v in value):
        return value
    if isinstance(value, Mapping) and controls is not None:
        unknown = sorted(str(k) for k in value if k not in controls)
        if unknown:
            raise error(f"{name}: {unknown} are not controls; the controls are {list(controls)}")
        for k, v in value.items():
            if not isinstance(v, str) or v not in CONTROL_INTERPOLATIONS:
                raise error(
                    f"{name}[{k!r}]: {v!r} is unknown; choose one of {list(CONTROL_INTERPOLATIONS)}"
                )
        cols = tuple(str(value.get(c, "linear")) for c in controls)
        return cols[0] if cols and len(set(cols)) == 1 else (cols or "linear")
    raise error(
        f"{name}: {value!r} is unknown; choose one of {list(CONTROL_INTERPOLATIONS)} "
        "or a mapping of control names to them"
    )


def control_slopes(time: FloatArray, u: FloatArray) -> FloatArray:
    """The cubic interpolation's slope du/dt at every sample, shaped as `u`
    (``(..., n_t, n_u)``, time on the second-to-last axis).

    Straight lines between samples (first-order hold) reconstruct a swing of
    frequency ω sampled every T with about ``sinc²(ωT/2)`` of its amplitude, a
    loss of ``(ωT)²/12`` that an identification reads as a control derivative
    too large by as much. The cubic Hermite interpolant between samples with
    these slopes keeps the controls C1 and the reconstruction's loss
    fourth order in ωT. Each slope is that of the parabola through the sample
    and its two neighbours (on a uniform grid ``(u[k+1] - u[k-1]) / 2T``:
    Catmull-Rom, Keys' cubic convolution with a = -1/2), at either end the
    parabola through the first or last three: local (a sample moves the
    controls over two intervals either side only), exact for quadratics, and
    on a uniform grid each interval's integral is ``T (-u[k-1] + 13 u[k] +
    13 u[k+1] - u[k+2]) / 24``, exact for cubics, so a state that integrates
    the controls errs by O(T⁴) against O(T²) with straight lines. The price is
    overshoot: a step or a surface held at its stop rings by up to about 7 %
    of the jump over the neighbouring intervals, which no surface did; hence
    straight lines stay the default, and the cubic is for smooth inputs
    (multisines, a pilot's stick) recorded at a rate not far above the
    motion's bandwidth.
    """
    u = np.asarray(u, dtype=np.float64)
    n_t = u.shape[-2]
    d = np.zeros_like(u)
    if n_t < 2:
        return d
    h = np.diff(np.asarray(time, dtype=np.float64))[:, None]  # (n_t - 1, 1)
    s = np.diff(u, axis=-2) / h  # secants, (..., n_t - 1, n_u)
    if n_t == 2:
        d[..., :, :] = s
        return d
    h0, h1 = h[:-1], h[1:]
    s0, s1 = s[..., :-1, :], s[..., 1:, :]
    # the parabola through three samples: its slope at the middle one weighs the
    # nearer neighbour's secant more
    d[..., 1:-1, :] = (h1 * s0 + h0 * s1) / (h0 + h1)
    d[..., 0, :] = ((2 * h0[0] + h1[0]) * s0[..., 0, :] - h0[0] * s1[..., 0, :]) / (h0[0] + h1[0])
    d[..., -1, :] = ((2 * h1[-1] + h0[-1]) * s1[..., -1, :] - h1[-1] * s0[..., -1, :]) / (
        h0[-1] + h1[-1]
    )
    return d


def hermite(u0: Any, u1: Any, a: Any, b: Any, s: Any) -> Any:
    """The cubic at fraction `s` of an interval from `u0` to `u1` whose end slopes,
    times the interval, exceed the chord ``u1 - u0`` by `a` and `b`: the straight
    line plus ``s (1 - s) ((1 - s) a - s b)``, which vanishes at both ends."""
    return u0 + s * (u1 - u0) + s * (1.0 - s) * ((1.0 - s) * a - s * b)


def _cubic_excess(
    time: FloatArray, u: FloatArray, interpolation: Interpolation = "cubic"
) -> tuple[FloatArray, FloatArray]:
    """Per interval, `hermite`'s a and b: ``(..., n_t - 1, n_u)`` each; zero in the
    columns a per-column `interpolation` keeps straight."""
    d = control_slopes(time, u)
    h = np.diff(np.asarray(time, dtype=np.float64))[:, None]
    du = np.diff(u, axis=-2)
    a, b = d[..., :-1, :] * h - du, d[..., 1:, :] * h - du
    if isinstance(interpolation, tuple):
        straight = np.array([v == "linear" for v in interpolation])
        a[..., straight] = 0.0
        b[..., straight] = 0.0
    return a, b


def control_excess(
    time: FloatArray, u: FloatArray, interpolation: Interpolation = "linear"
) -> FloatArray:
    """`hermite`'s a and b of every interval side by side, ``(..., n_t - 1, 2, n_u)``
    for controls ``(..., n_t, n_u)``: what the compiled RK4 programs take beside the
    controls, one program for either interpolation. Zero for straight lines (and in the
    columns a per-column `interpolation` keeps straight), where ``hermite`` adds
    nothing to the straight line: the same values, bit for bit."""
    u = np.asarray(u, dtype=np.float64)
    n_t = u.shape[-2]
    if interpolation == "linear" or n_t < 2:
        return np.zeros((*u.shape[:-2], max(n_t - 1, 0), 2, u.shape[-1]))
    a, b = _cubic_excess(time, u, interpolation)
    return np.ascontiguousarray(np.stack([a, b], axis=-2))


def control_nodes(
    u: FloatArray,
    substeps: int,
    time: FloatArray | None = None,
    interpolation: Interpolation = "linear",
    *,
    hold: bool = False,
) -> FloatArray:
    """Controls at every RK4 node: shape (n_t - 1, 2*substeps + 1, n_u, batch); "cubic"
    `interpolation` needs the record's `time`; with `hold` the interval's first sample
    at every node."""
    # u: (batch, n_t, n_u)
    frac = np.arange(2 * substeps + 1) / (2 * substeps)
    if hold:
        frac = np.zeros_like(frac)
    lo = u[:, :-1, None, :]
    hi = u[:, 1:, None, :]
    if interpolation == "linear":
        nodes = lo + frac[None, None, :, None] * (hi - lo)  # (B, n_t-1, 2m+1, n_u)
    else:
        if time is None:
            raise SimulationError("control_nodes: cubic controls need the record's time")
        a, b = _cubic_excess(time, u, interpolation)
        s = frac[None, None, :, None]
        nodes = hermite(lo, hi, a[:, :, None, :], b[:, :, None, :], s)
    return np.ascontiguousarray(np.transpose(nodes, (1, 2, 3, 0)))


def controls_at(
    time: FloatArray, u: FloatArray, t: FloatArray, interpolation: Interpolation = "linear"
) -> FloatArray:
    """One record's controls u (n_t, n_u) at times t (held at the first and last samples
    outside the record), interpolated as `interpolation` says: (t.size, n_u)."""
    t = np.asarray(t, dtype=np.float64)
    if interpolation == "linear" or time.size < 2:
        return np.stack([np.interp(t, time, u[:, j]) for j in range(u.shape[1])], axis=1)
    k = np.clip(np.searchsorted(time, t, side="right") - 1, 0, time.size - 2)
    s = np.clip((t - time[k]) / (time[k + 1] - time[k]), 0.0, 1.0)[:, None]
    a, b = _cubic_excess(time, u, interpolation)
    out: FloatArray = hermite(u[k], u[k + 1], a[k], b[k], s)
    return out


def shifted_controls(
    time: FloatArray,
    controls: FloatArray,
    columns: Sequence[int],
    delays: Sequence[float] | FloatArray,
    interpolation: Interpolation = "linear",
) -> FloatArray:
    """The controls with column ``columns[i]`` delayed by ``delays[i]`` seconds, on
    the record's own time grid: ``u(t_k - tau)`` at each sample time ``t_k``,
    interpolated between the samples as the simulation is told (piecewise-linearly
    by default, or the cubic of `aeroid.models.integration.control_slopes`) and
    held at the first and last samples outside them.

    The simulation then joins these delayed samples between sample times like any
    control: a whole-sample delay is exactly ``u(t - tau)``, a fractional one a
    linear-interpolation fractional-delay filter (the delayed control's corners at
    ``t_j + tau`` are cut by the chord between sample times)."""
    out = np.array(controls, dtype=np.float64, copy=True)
    # from the record's start: on a clock at 1.7e9 s a time's last digit is 2.4e-7 s, and
    # t - tau would round a shift of a few microseconds (a delay's derivative) away
    since = np.asarray(time, dtype=np.float64) - float(time[0]) if len(time) else time
    for j, tau in zip(columns, np.asarray(delays, dtype=np.float64).tolist(), strict=True):
        if tau == 0.0:
            continue
        how = interpolation[j] if isinstance(interpolation, tuple) else interpolation
        if how == "linear":
            out[:, j] = np.interp(since - tau, since, controls[:, j])
        else:
            out[:, j] = controls_at(since, controls[:, j : j + 1], since - tau, how)[:, 0]
    return out
