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
    from ..models.replay import with_state_biases

    return with_state_biases(model, biased, _STATE_BIAS_PREFIX)


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


def _with_bias_parameters(
    model: Any,
    datas: list[Any],
    on_outputs: list[str],
    on_states: list[str],
) -> tuple[Any, list[Any], list[tuple[int, str, str]], list[str]]:
    """The model with each manoeuvre's biases as parameters, for the filter error.

    Biases are per manoeuvre while parameters are shared, so each record gets a
    constant control that is 1 on it and 0 on the others, and a bias enters as
    that control times its parameter: ``y += sum_i d_i b_i`` on an output,
    ``x' += sum_i d_i b_i`` on a state equation. Both stay affine in the
    controls, so a linear model stays linear. Returns the model, the records
    with their controls added, and per bias (manoeuvre, kind, name) in the
    order of the parameters appended (the names are ``model_bias_names``).
    """
    import dataclasses

    from ..models.model import Model

    states = list(model.states)
    outputs = list(model.output_names)
    controls = list(model.controls)
    taken = set(states) | set(controls) | set(outputs) | set(model.parameters)

    def fresh(name: str) -> str:
        while name in taken:
            name = "_" + name
        taken.add(name)
        return name

    marks = [fresh(f"manoeuvre_{i}") for i in range(len(datas))]
    # output error's order: each manoeuvre's state biases, then each one's output biases
    layout = [(i, "state", s) for i in range(len(datas)) for s in on_states]
    layout += [(i, "output", o) for i in range(len(datas)) for o in on_outputs]
    # readable where the names allow (the fit's warnings name them), else numbered
    pnames = [
        fresh(
            f"bias_{i}_{'state_' if kind == 'state' else ''}{name}"
            if name.isidentifier()
            else f"bias_{i}_{kind}_{k}"
        )
        for k, (i, kind, name) in enumerate(layout)
    ]
    n_u = len(controls)
    f = model.dynamics
    h = model.measurement
    out_of_state = np.array([states.index(o) if o in states else -1 for o in outputs])

    # per bias: its record's control column, its parameter and the unit vector of its
    # row, built here: the compiled path traces the functions below with jax.numpy,
    # whose arrays take no in-place update
    terms: dict[str, list[tuple[int, str, Any]]] = {"state": [], "output": []}
    for (i, kind, name), pn in zip(layout, pnames, strict=True):
        rows = states if kind == "state" else outputs
        unit = np.zeros(len(rows))
        unit[rows.index(name)] = 1.0
        terms[kind].append((n_u + i, pn, unit))

    def added(base: Any, kind: str, u: Any, p: Mapping[str, Any]) -> Any:
        for col, pn, unit in terms[kind]:
            value = u[col] * p[pn]
            base = base + np.reshape(unit, (unit.size,) + (1,) * np.ndim(value)) * value
        return base

    def dynamics(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        xd = np.reshape(np.asarray(f(t, x, u[:n_u], p)), (len(states), *np.shape(x)[1:]))
        return added(xd, "state", u, p)

    def measurement(t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        if h is None:
            y = x[out_of_state]
        else:
            y = np.reshape(np.asarray(h(t, x, u[:n_u], p)), (len(outputs), *np.shape(x)[1:]))
        return added(y, "output", u, p)

    kwargs: dict[str, Any] = {}
    init_fields = {fl.name for fl in dataclasses.fields(Model) if fl.init}
    for key in ("version", "linear"):
        if key in init_fields and hasattr(model, key):
            kwargs[key] = getattr(model, key)
    wrapped = Model(
        states=states,
        controls=[*controls, *marks],
        parameters={**dict(model.parameters), **dict.fromkeys(pnames, 0.0)},
        dynamics=dynamics,
        outputs=outputs,
        # a model that measures its states directly keeps doing so without output biases
        measurement=measurement if (on_outputs or h is not None) else None,
        name=model.name,
        **kwargs,
    )
    n_t = [d.n_samples for d in datas]
    marked = [
        d.with_channels({m: np.full(n_t[i], float(i == j)) for j, m in enumerate(marks)})
        for i, d in enumerate(datas)
    ]
    return wrapped, marked, layout, pnames


def _bias_parameters_out(
    fitted: IdentificationResult, pnames: list[str], layout: list[tuple[int, str, str]]
) -> IdentificationResult:
    """Report the bias parameters of `_with_bias_parameters` as `biases` per manoeuvre, in
    `extra_stderr` and in `full_names` after the parameters and delays (as output error)."""
    label = {
        pn: f"bias[{i}].{name}" if kind == "output" else f"bias[{i}].state.{name}"
        for pn, (i, kind, name) in zip(pnames, layout, strict=True)
    }
    n_man = 1 + max(i for i, _, _ in layout)
    biases: list[dict[str, float]] = [{} for _ in range(n_man)]
    for pn, (i, kind, name) in zip(pnames, layout, strict=True):
        biases[i][name if kind == "output" else f"state.{name}"] = fitted.parameters[pn]
    full = list(fitted.full_names)
    kept = [k for k, n in enumerate(fitted.parameter_names) if n not in label]
    n_e = len(fitted.parameter_names)
    order = kept + [full.index(pn) for pn in pnames] + list(range(n_e, len(full)))
    cov = np.asarray(fitted.covariance)[np.ix_(kept, kept)]
    white = np.asarray(fitted.covariance_white)[np.ix_(kept, kept)]
    bars = {label[pn]: fitted.stderr[pn] for pn in pnames}
    return replace(
        fitted,
        parameters={k: v for k, v in fitted.parameters.items() if k not in label},
        stderr={k: v for k, v in fitted.stderr.items() if k not in label},
        covariance=cov,
        covariance_white=white,
        parameter_names=tuple(fitted.parameter_names[k] for k in kept),
        fixed={k: v for k, v in fitted.fixed.items() if k not in label},
        unidentifiable=tuple(tuple(label.get(n, n) for n in c) for c in fitted.unidentifiable),
        biases=tuple(biases),
        extra_stderr={**bars, **fitted.extra_stderr},
        full_covariance=np.asarray(fitted.full_covariance)[np.ix_(order, order)],
        full_names=tuple(label.get(full[k], full[k]) for k in order),
    )
