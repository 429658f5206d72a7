"""The model's side of a frequency-response comparison (`aeroid.frequency`): its
analytic transfer function, exact or linearised, or its outputs simulated on the
record.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import SimulationError
from ..io.data import FlightData, measured_start
from ..models import integration as _integrate
from ..models.model import Model, SimulatorModel, simulator_outputs
from ._transfer import state_space_response

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def _affine_measurement(
    model: Model, p: Mapping[str, FloatArray], time: FloatArray
) -> tuple[FloatArray, FloatArray] | None:
    """(C, D) if the model's outputs are affine in state and control over `time`, else None."""
    n_x, n_u = model.n_states, model.n_controls
    if model._measurement_batch is None:
        return _state_outputs(model)
    p1 = {k: np.asarray(v[:1], dtype=np.float64) for k, v in p.items()}
    mats, _ = _integrate.lti_form(
        model._measurement_batch, time, n_x, n_u, p1, trusted=model.linear is True
    )
    if mats is None:
        return None
    return mats[0][0], mats[1][0]


def _exact_response(
    model: Model, values: Mapping[str, float], time: FloatArray, freqs: FloatArray
) -> ComplexArray | None:
    """Analytic H(j 2π f) of shape (n_f, n_u, n_y), or None when the model is not LTI.

    LTI over the record's own time grid: a model whose forcing or gains change
    during the record has no transfer function.
    """
    if not model._maybe_lti:
        return None
    p = {k: np.array([float(v)]) for k, v in values.items()}
    mats, _ = _integrate.lti_form(
        model._dynamics_batch,
        time,
        model.n_states,
        model.n_controls,
        p,
        trusted=model.linear is True,
    )
    if mats is None:
        return None
    cd = _affine_measurement(model, p, time)
    if cd is None:
        return None
    return _transfer(mats[0][0], mats[1][0], *cd, freqs)


def _state_outputs(model: Model) -> tuple[FloatArray, FloatArray]:
    """(C, D) of a model without a measurement function: its outputs are states."""
    c = np.zeros((model.n_outputs, model.n_states))
    for i, o in enumerate(model.output_names):
        c[i, list(model.states).index(o)] = 1.0
    return c, np.zeros((model.n_outputs, model.n_controls))


def _transfer(
    a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray, freqs: FloatArray
) -> ComplexArray:
    """``C (j 2π f I - A)^-1 B + D`` at each of `freqs` (Hz), shape (n_f, n_u, n_y)."""
    with np.errstate(all="ignore"):
        h = state_space_response(a, b, c, d, 2.0 * np.pi * freqs)  # (n_f, n_y, n_u)
    return np.transpose(h, (0, 2, 1))


def _linearised_response(
    model: Model,
    values: Mapping[str, float],
    t0: float,
    x_ref: FloatArray,
    u_ref: FloatArray,
    freqs: FloatArray,
) -> ComplexArray | None:
    """H(j 2π f), shape (n_f, n_u, n_y), of the model linearised at (`x_ref`, `u_ref`).

    Central differences of the dynamics and the measurement about the
    reference (the record's first sample: its trim, for a manoeuvre flown from
    trim), all in one batched call each. None where a function cannot be
    evaluated there or gives non-finite values.
    """
    n_x = model.n_states
    z = np.concatenate([x_ref, u_ref]).astype(np.float64)
    n = z.size
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    Z = np.repeat(z[:, None], 2 * n, axis=1)
    cols = np.arange(n)
    Z[cols, 2 * cols] += h
    Z[cols, 2 * cols + 1] -= h
    P = {k: np.full(2 * n, float(v)) for k, v in values.items()}

    def jacobian(f: Any) -> FloatArray | None:
        try:
            with np.errstate(all="ignore"):
                F = np.asarray(f(float(t0), Z[:n_x], Z[n_x:], P), dtype=np.float64)
        except Exception:  # a function that cannot be evaluated there: simulated instead
            return None
        if not np.all(np.isfinite(F)):
            return None
        return (F[:, 0::2] - F[:, 1::2]) / (2.0 * h)

    J = jacobian(model._dynamics_batch)
    if J is None:
        return None
    if model._measurement_batch is None:
        c, d = _state_outputs(model)
    else:
        Jm = jacobian(model._measurement_batch)
        if Jm is None:
            return None
        c, d = Jm[:, :n_x], Jm[:, n_x:]
    return _transfer(J[:, :n_x], J[:, n_x:], c, d, freqs)


def _reference_state(model: Model, data: FlightData, x0: Any) -> FloatArray:
    """The state a response is linearised about: `x0` (a mapping or a vector), else the
    record's first sample of each measured state (0 for the others)."""
    if x0 is None:
        x0 = measured_start(data, model.states)
    if isinstance(x0, Mapping):
        return np.array([float(x0.get(s, 0.0)) for s in model.states])
    return np.asarray(x0, dtype=np.float64).reshape(-1)[: model.n_states]


def _simulated_outputs(
    model: Model | SimulatorModel, data: FlightData, values: Mapping[str, float], x0: Any
) -> FloatArray:
    if isinstance(model, Model):
        if x0 is None:
            x0 = measured_start(data, model.states)
        sim = model.simulate_batch(data.time, data, x0, values, method="auto")
        if not sim.ok[0]:
            raise SimulationError(
                f"frequency_response: model {model.name!r} failed to simulate the record: "
                f"{sim.failure[0]}"
            )
        return np.asarray(sim.outputs[0])
    return simulator_outputs(
        model, lambda: model.simulate_data(data, x0=x0, parameters=values), data.n_samples
    )
