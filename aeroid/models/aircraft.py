"""Standard flight-mechanics models: longitudinal, lateral-directional and six degrees of freedom.

The equations of motion and non-dimensionalisation follow Klein & Morelli,
*Aircraft System Identification* (2006), ch. 3, which agrees with
Jategaonkar, *Flight Vehicle System Identification*, ch. 3; the sensor
models (accelerometers and air-data vanes off the centre of gravity) are the
rigid-body kinematic corrections of their data-compatibility chapters:

* `longitudinal`: nonlinear, stability (wind) axes, states V, α, θ, q (h);
* `lateral`: lateral-directional about a trim (V0, α0, θ0), states β, p, r, φ (ψ);
* `six_dof`: nonlinear, body axes, states u, v, w, p, q, r, φ, θ, ψ (position);
* `longitudinal_linear`, `lateral_linear`: small perturbations with
  dimensional derivatives (``M_alpha``, ``L_p``, ``N_r``, ...).

The aerodynamic coefficients are linear-in-parameters expansions whose terms
the user chooses (parameters ``CL_alpha``, ``Cm_q``, ``Cn_delta_r``,
``CD_0``): regressors, their products and absolute values (``"abs(beta)"``,
``CD_abs_beta``, the nonsmooth candidate regressors of Klein & Morelli ch. 5). The constants of an aircraft (mass, inertias, reference geometry,
air density, sensor positions, thrust line) are one validated record,
`AircraftConstants`. Every model is an `aeroid.Model` (an `AircraftModel`,
whose ``summary()`` prints its equations); its functions broadcast over
batches and use only module-level ``np`` calls, which the compiled path
(`identify`'s default ``gradient="auto"``) translates to `jax.numpy`, and so
do `simulate_rk4`, ``gradient="jax"`` and ``backend="jax"`` for these models
(a user's model they trace as written). `trim` finds a steady flight
condition, `linearize` the
Jacobians about it, and `model_from_config` builds a model from a campaign
config's mapping.

The code lives in private modules by job: `_aircraft_parts` (the ISA, the
constants, coefficient expansions, option checks and the `AircraftModel`
record), `_aircraft_nonlinear`, `_aircraft_six_dof`, `_aircraft_linear` (the
builders) and `_aircraft_trim`; this module is their public face.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import MISSING, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ModelDefinitionError
from ._aircraft_linear import decoupled, lateral_linear, longitudinal_linear
from ._aircraft_nonlinear import lateral, longitudinal
from ._aircraft_parts import _LATERAL_ONLY, AircraftConstants, AircraftModel, isa_density
from ._aircraft_six_dof import six_dof
from ._aircraft_trim import Linearization, TrimResult, linearize, trim

FloatArray = NDArray[np.float64]

__all__ = [
    "AircraftConstants",
    "AircraftModel",
    "Linearization",
    "TrimResult",
    "decoupled",
    "isa_density",
    "lateral",
    "lateral_linear",
    "linearize",
    "longitudinal",
    "longitudinal_linear",
    "model_from_config",
    "six_dof",
    "trim",
]

# the records keep the module their users name (reprs, pickles and stored type names)
for _record in (AircraftConstants, AircraftModel, Linearization, TrimResult):
    _record.__module__ = __name__
del _record

# -- models from a configuration --------------------------------------------------------------------


_FACTORIES: dict[str, Callable[..., AircraftModel]] = {
    "longitudinal": longitudinal,
    "lateral": lateral,
    "six_dof": six_dof,
    "longitudinal_linear": longitudinal_linear,
    "lateral_linear": lateral_linear,
}


def model_from_config(spec: Mapping[str, Any]) -> AircraftModel:
    """Build an aircraft model from a plain mapping (a campaign config's YAML).

    ``aircraft`` names the model (``longitudinal``, ``lateral``, ``six_dof``,
    ``longitudinal_linear``, ``lateral_linear``); ``constants`` holds the
    `AircraftConstants` fields (the nonlinear models need it); every other key
    is a keyword of that model's function (``V0``, ``terms``, ``parameters``,
    ``outputs``, ...)::

        aircraft: longitudinal
        V0: 53.6
        constants: {mass: 1247, Ixx: 1421, Iyy: 4067, Izz: 4786, S: 17.09,
                    b: 10.18, cbar: 1.74, altitude: 1500}
        terms: {CL: ["0", alpha, q, delta_e]}
        parameters: {CL_alpha: 4.4, Cm_alpha: -0.7}

    Parameters
    ----------
    spec : mapping of str to Any
        The model's name, constants and keywords, as above.

    Returns
    -------
    AircraftModel

    Raises
    ------
    ModelDefinitionError
        An unknown model or key, or anything the model function rejects; the
        message names it.
    """
    if not isinstance(spec, Mapping):
        raise ModelDefinitionError(f"aircraft model: expected a mapping, got {spec!r}")
    options = dict(spec)
    kind = options.pop("aircraft", None)
    if kind == "decoupled":
        unknown = sorted(set(options) - {"longitudinal", "lateral", "name", "version"})
        if unknown or "longitudinal" not in options or "lateral" not in options:
            raise ModelDefinitionError(
                "aircraft model 'decoupled': expected the keys 'longitudinal' and 'lateral' "
                f"(each an aircraft model mapping), and optionally 'name', 'version'; got {sorted(options)}"
            )
        parts = {k: model_from_config(options.pop(k)) for k in ("longitudinal", "lateral")}
        return decoupled(parts["longitudinal"], parts["lateral"], **options)
    if kind not in _FACTORIES:
        raise ModelDefinitionError(
            f"aircraft: expected one of {sorted([*_FACTORIES, 'decoupled'])}, got {kind!r}"
        )
    factory = _FACTORIES[kind]
    allowed = [
        n
        for n, prm in inspect.signature(factory).parameters.items()
        if prm.kind is inspect.Parameter.KEYWORD_ONLY
    ]
    takes_constants = "constants" in inspect.signature(factory).parameters
    raw = options.pop("constants", None)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ModelDefinitionError(
            f"aircraft model {kind!r}: unknown keys {unknown}; allowed: "
            f"{sorted([*allowed, 'constants'] if takes_constants else allowed)}"
        )
    for key in ("terms", "parameters"):
        if key in options and isinstance(options[key], Mapping):
            options[key] = {
                str(k): ([str(t) for t in v] if isinstance(v, (list, tuple)) else v)
                for k, v in options[key].items()
            }
    if not takes_constants:
        if raw is not None:
            raise ModelDefinitionError(
                f"aircraft model {kind!r}: takes no constants (its derivatives are dimensional)"
            )
        return factory(**options)
    if not isinstance(raw, Mapping):
        raise ModelDefinitionError(
            f"aircraft model {kind!r}: 'constants' must be a mapping of AircraftConstants fields"
        )
    names = {f.name for f in fields(AircraftConstants)}
    bad = sorted(set(raw) - names)
    if bad:
        raise ModelDefinitionError(f"constants: unknown fields {bad}; fields: {sorted(names)}")
    values: dict[str, Any] = {k: (tuple(v) if isinstance(v, list) else v) for k, v in raw.items()}
    needed = {f.name for f in fields(AircraftConstants) if f.default is MISSING}
    needed |= {"Iyy", "S", "cbar"} | (set() if kind == "longitudinal" else set(_LATERAL_ONLY))
    missing = sorted(needed - set(values))
    if missing:
        raise ModelDefinitionError(f"constants: missing {missing}")
    return factory(AircraftConstants(**values), **options)
