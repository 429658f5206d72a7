"""State biases: constant offsets on the state equations, appended to a fit's parameters and
taken out of its result again.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import IdentificationError
from ..io.data import plain
from ._identification_record import STATE_BIAS_PREFIX as _STATE_BIAS_PREFIX
from ._identification_record import IdentificationResult
from ._identification_start import _select


def _bias_choice(option: Any, outputs: list[str], states: list[str]) -> tuple[list[str], list[str]]:
    """(output biases, state-equation biases) from `estimate_bias` (see `identify`)."""
    if not isinstance(option, Mapping):
        return _select(option, outputs, "estimate_bias"), []
    on_outputs: list[str] = []
    on_states: list[str] = []
    for name, kind in option.items():
        if isinstance(kind, str):
            kinds = [kind]
        else:
            try:
                kinds = list(kind)
            except TypeError:
                kinds = [kind]
        for k in kinds:
            if k == "output":
                if name not in outputs:
                    raise IdentificationError(
                        f"estimate_bias: {name!r} is not a fitted output; fitted outputs: {outputs}"
                    )
                if name not in on_outputs:
                    on_outputs.append(name)
            elif k == "state":
                if not states:
                    raise IdentificationError(
                        f"estimate_bias[{name!r}]: a 'state' bias enters a state equation, "
                        "and the model has no states; estimate an 'output' bias instead"
                    )
                if name not in states:
                    raise IdentificationError(
                        f"estimate_bias: {name!r} is not a state of the model; states: {states}"
                    )
                if name not in on_states:
                    on_states.append(name)
            else:
                raise IdentificationError(
                    f"estimate_bias[{name!r}]: expected 'output' or 'state', got {plain(k)}"
                )
    return on_outputs, on_states


def _with_state_biases(model: Any, biased: list[str]) -> tuple[Any, list[str]]:
    """The model with one constant state per biased state equation: ``b' = 0`` and
    ``x_k' = f_k + b``.

    The biases are then the initial values of those states, estimated per
    manoeuvre by the initial-state machinery (each manoeuvre's simulations
    carry only its own bias columns).
    """
    import dataclasses

    from ..models.model import Model

    states = list(model.states)
    n = len(states)
    taken = set(states) | set(model.controls) | set(model.output_names)
    extra: list[str] = []
    for s in biased:
        name = _STATE_BIAS_PREFIX + s
        while name in taken:
            name = "_" + name
        taken.add(name)
        extra.append(name)
    f = model.dynamics
    h = model.measurement

    # Functional form (no in-place update) so that a compiled path can trace it.
    select = np.zeros((n, len(biased)))
    select[[states.index(s) for s in biased], np.arange(len(biased))] = 1.0

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


def _state_biases_out(
    fitted: IdentificationResult, extra: list[str], biased: list[str]
) -> IdentificationResult:
    """Report the bias states of `_with_state_biases` as state-equation biases."""
    initial = []
    biases = []
    for xs, bs in zip(fitted.initial_states, fitted.biases, strict=True):
        xs = dict(xs)
        bs = dict(bs)
        for name, s in zip(extra, biased, strict=True):
            bs[f"state.{s}"] = xs.pop(name)
        initial.append(xs)
        biases.append(bs)
    rename = {}
    for i in range(len(fitted.initial_states)):
        for name, s in zip(extra, biased, strict=True):
            rename[f"x0[{i}].{name}"] = f"bias[{i}].state.{s}"
    moved = {rename[k]: v for k, v in fitted.extra_stderr.items() if k in rename}
    kept = {k: v for k, v in fitted.extra_stderr.items() if k not in rename}
    return replace(
        fitted,
        initial_states=tuple(initial),
        biases=tuple(biases),
        extra_stderr={**kept, **moved},
        full_names=tuple(rename.get(k, k) for k in fitted.full_names),
    )
