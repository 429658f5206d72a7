"""Replaying a fit as it was fitted: its initial state, output biases and state-equation
biases on a record it was fitted to."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ModelDefinitionError
from ..io.data import FlightData
from .model import Model, fitted_start

__all__ = ["FittedReplay", "fitted_replay", "with_state_biases"]

_STATE_KEY = "state."  # how a fit's `biases` name a state-equation bias


@dataclass(frozen=True)
class FittedReplay:
    """What simulates a fit again on a record it was fitted to (`fitted_replay`).

    Attributes
    ----------
    model : Model or SimulatorModel
        The model, with one constant state per state-equation bias the fit
        estimated for the record (``x_dot = f + b``, ``b_dot = 0``).
    x0 : mapping, array or None
        The initial state of `model` (its bias states at the biases).
    output_biases : dict of str to float
        Constants to add to the simulated outputs.
    bias_states : dict of str to str
        Biased state -> the constant state of `model` that holds its bias.
    """

    model: Any
    x0: Any
    output_biases: dict[str, float]
    bias_states: dict[str, str]


def with_state_biases(
    model: Any, biased: Sequence[str], prefix: str = "bias."
) -> tuple[Any, list[str]]:
    """The model with one constant state per biased state equation: ``b' = 0`` and
    ``x_k' = f_k + b``; returns it and the names of the added states.

    The biases are then the initial values of those states (which a fit
    estimates per manoeuvre as initial states).
    """
    if not isinstance(model, Model) or model.dynamics is None:
        raise ModelDefinitionError(
            f"state biases {list(biased)} enter a state equation: they need an aeroid.Model "
            f"with dynamics, got {type(model).__name__} {getattr(model, 'name', '')!r}"
        )
    states = list(model.states)
    n = len(states)
    taken = set(states) | set(model.controls) | set(model.output_names)
    extra: list[str] = []
    for s in biased:
        name = prefix + s
        while name in taken:
            name = "_" + name
        taken.add(name)
        extra.append(name)
    f = model.dynamics
    h = model.measurement
    unknown = [s for s in biased if s not in states]
    if unknown:
        raise ModelDefinitionError(f"state biases {unknown}: not states of the model; {states}")

    # Functional form (no in-place update) so that a compiled path can trace it.
    select = np.zeros((n, len(extra)))
    select[[states.index(s) for s in biased], np.arange(len(extra))] = 1.0

    def dynamics(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        xd = np.reshape(np.asarray(f(t, x[:n], u, p), dtype=np.float64), (n, *np.shape(x)[1:]))
        b = x[n:]
        return np.concatenate([xd + select @ b, np.zeros_like(b)], axis=0)

    def measurement(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        assert h is not None
        return h(t, x[:n], u, p)

    kwargs: dict[str, Any] = {}
    init_fields = {fl.name for fl in dataclasses.fields(Model) if fl.init}
    for key in ("version", "linear"):  # carried over where this version has them
        if key in init_fields and hasattr(model, key):
            kwargs[key] = getattr(model, key)
    wrapped = Model(
        states=[*states, *extra],
        controls=list(model.controls),
        parameters=dict(model.parameters),
        dynamics=dynamics,
        outputs=list(model.output_names),
        measurement=None if h is None else measurement,
        name=model.name,
        **kwargs,
    )
    return wrapped, extra


def fitted_replay(model: Any, result: Any, data: FlightData, x0: Any = None) -> FittedReplay:
    """The model, initial state and output biases that simulate `data` as a fit did.

    On a record the fit was fitted to: from its initial state (unless `x0`
    is given), with its output biases and its state-equation biases; on any
    other record (or for a mapping of values) the model as it is, from `x0`.
    """
    fitted_x0, biases = fitted_start(result, data)
    if x0 is None:
        x0 = fitted_x0
    on_states = {k[len(_STATE_KEY) :]: v for k, v in biases.items() if k.startswith(_STATE_KEY)}
    outputs = {k: float(v) for k, v in biases.items() if not k.startswith(_STATE_KEY)}
    if not on_states:
        return FittedReplay(model, x0, outputs, {})
    wrapped, extra = with_state_biases(model, list(on_states))
    values = [float(v) for v in on_states.values()]
    if isinstance(x0, Mapping):
        start: Any = {**dict(x0), **dict(zip(extra, values, strict=True))}
    else:  # an array for the model's own states, given as `x0`
        start = np.concatenate([np.ravel(np.asarray(x0, dtype=np.float64)), values])
    return FittedReplay(wrapped, start, outputs, dict(zip(on_states, extra, strict=True)))
