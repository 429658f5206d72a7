"""Parameter values, initial states and delayed controls a simulation takes from a fit."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..errors import AeroidError, ModelDefinitionError
from ..io.data import FlightData, as_float, fingerprint, plain
from ._controls import shifted_controls


def _names(value: Sequence[str] | str, what: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    try:
        names = tuple(value)
    except TypeError:
        raise ModelDefinitionError(
            f"{what}: expected a sequence of names, got {plain(value)}"
        ) from None
    for n in names:
        if not isinstance(n, str) or not n:
            raise ModelDefinitionError(f"{what}: every name must be a non-empty string, got {n!r}")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ModelDefinitionError(f"{what}: duplicate names {dupes}")
    return names


def resolve_parameters(
    model: Any,
    parameters: Any,
    *,
    error: type[AeroidError] = ModelDefinitionError,
    delays: bool = False,
) -> dict[str, float]:
    """Merge a parameter dict (or any result with ``.parameters``) onto the model's nominal values.

    Unknown names raise `error` naming them; values must be finite numbers.
    Extra entries a result may carry (such as ``sigma_<output>`` noise
    parameters of an inference result) are ignored when they are not model
    parameters.
    """
    nominal = dict(model.parameters)
    # ``tau_<control>`` entries a caller that applies them takes (`control_delays`)
    taken = {f"tau_{c}" for c in getattr(model, "controls", ())} - set(nominal) if delays else set()
    if parameters is None:
        return {k: float(v) for k, v in nominal.items()}
    from_result = not isinstance(parameters, Mapping) and hasattr(parameters, "parameters")
    values = parameters.parameters if from_result else parameters
    if not isinstance(values, Mapping):
        raise error(
            f"parameters: expected a dict of name -> value or a result with .parameters, "
            f"got {type(parameters).__name__}"
        )
    out = {k: float(v) for k, v in nominal.items()}
    for name, value in values.items():
        if name not in nominal:
            if from_result or name in taken:
                continue
            raise error(
                f"parameter {name!r} is not a parameter of model {model.name!r}; "
                f"its parameters are {sorted(nominal)}"
            )
        v = as_float(value)
        if v is None:
            raise error(f"parameter {name!r}: expected a number, got {plain(value)}")
        if not np.isfinite(v):
            raise error(f"parameter {name!r}: value {v!r} is not finite")
        out[name] = v
    return out


def fitted_manoeuvre(result: Any, data: FlightData) -> int | None:
    """Which of a fit's manoeuvres `data` is, or None when the fit was not fitted to it.

    Results stored before records were fingerprinted answer their first
    manoeuvre, as they always did.
    """
    if not getattr(result, "initial_states", None):
        return None
    fitted = tuple(getattr(result, "data_fingerprints", ()) or ())
    if not fitted:
        return 0
    mark = fingerprint(data)
    return fitted.index(mark) if mark in fitted else None


def fitted_start(result: Any, data: FlightData) -> tuple[dict[str, float] | None, dict[str, float]]:
    """The initial state and biases a fit used for `data`, if it was fitted to `data`.

    An identification result holds one initial state (measured, given or
    estimated) and one set of biases per manoeuvre (output biases by output
    name, state-equation biases as ``"state.<name>"``). Simulating one of
    those records again, a function should start where the fit did; any
    other record (cross-validation on another manoeuvre) starts from its own
    measured state, without the fit's biases. Returns ``(None, {})`` then.
    """
    i = fitted_manoeuvre(result, data)
    if i is None:
        return None, {}
    biases = tuple(getattr(result, "biases", ()) or ())
    return dict(result.initial_states[i]), (dict(biases[i]) if i < len(biases) else {})


def delayed_controls(result: Any, data: FlightData) -> FlightData:
    """`data` with the controls an identification delayed shifted by their delays.

    A result whose fit estimated pure time delays (``result.time_delays``,
    control -> seconds) describes a vehicle whose controls act as
    ``u(t - tau)``: its model is simulated on the controls delayed the same
    way, ``u(t_k - tau)`` at the sample times joined piecewise-linearly as
    `identify` does (see its ``time_delays``), and held at the
    first sample before it. Unlike the initial state and the output biases, a
    delay belongs to the vehicle, so it applies on any record. Other values
    of `result` (a mapping, None) leave `data` as it is.
    """
    delays = {
        c: float(tau)
        for c, tau in dict(getattr(result, "time_delays", None) or {}).items()
        if c in data and float(tau) != 0.0
    }
    if not delays:
        return data
    names = list(delays)
    u = np.column_stack([data.channels[c] for c in names])
    moved = shifted_controls(data.time, u, range(len(names)), list(delays.values()))
    return data.with_channels({c: moved[:, j] for j, c in enumerate(names)})


def control_delays(
    model: Any, parameters: Any, *, error: type[AeroidError] = ModelDefinitionError
) -> dict[str, float]:
    """The pure control delays (control -> seconds) a parameter set carries.

    A fit that estimated delays holds them in ``result.time_delays`` and among
    its parameters as ``tau_<control>``; a mapping carries them the same way
    (a draw of `propagate`, a posterior sample). Names that are parameters of
    the model itself stay parameters.
    """
    if parameters is None:
        return {}
    controls = tuple(getattr(model, "controls", ()))
    if not isinstance(parameters, Mapping):
        held = dict(getattr(parameters, "time_delays", None) or {})
        return {c: float(held[c]) for c in controls if c in held}
    out: dict[str, float] = {}
    for c in controls:
        name = f"tau_{c}"
        if name not in parameters or name in model.parameters:
            continue
        v = as_float(parameters[name])
        if v is None or not np.isfinite(v):
            raise error(
                f"parameter {name!r} (the delay of control {c!r}): expected a finite "
                f"number of seconds, got {plain(parameters[name])}"
            )
        out[c] = v
    return out
