"""Optional JAX backend: the jit-compiled, differentiable RK4 rollout (``aeroid[jax]``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import SimulationError
from .model import SimulationResult, resolve_parameters

__all__ = ["simulate_rk4"]


@dataclass(frozen=True, eq=False)
class _TracedSimulationResult(SimulationResult):
    """A rollout a caller's JAX transformation runs through: its arrays stay JAX arrays
    (immutable already), which numpy could not hold."""

    def __post_init__(self) -> None:
        pass


def simulate_rk4(
    model: Any,
    time: ArrayLike,
    controls: Any = None,
    x0: Any = None,
    parameters: Any = None,
    *,
    substeps: int = 4,
) -> SimulationResult:
    """Simulate a model with the jit-compiled fixed-step RK4 of the JAX backend.

    The rollout takes `substeps` classical RK4 steps per sample interval with
    the controls linear between samples, in 64-bit floats; it is the
    integrator behind ``identify(..., gradient="jax")`` and
    ``infer(..., backend="jax")``, exposed here for parity checks against
    `Model.simulate`. The first call for a model and grid length compiles;
    later calls reuse the compiled code.

    The rollout is differentiable: under a caller's JAX transformation
    (`jax.grad`, `jax.jacfwd`, `jax.vmap`, `jax.jit`) of parameter values, of
    `x0` or of the controls, the result holds JAX arrays the derivative runs
    through (``jax.jacfwd(lambda k: simulate_rk4(m, t, None, [1.0], {"k": k})
    .state("x"))(0.5)``); the time grid stays concrete, the controls are straight
    between samples, and the non-finite check is left to the caller.

    Parameters
    ----------
    model : Model
        A model whose dynamics (and measurement) are written with `jax.numpy`.
    time : array_like, shape (n_t,)
        Strictly increasing sample times; the states land exactly on them.
    controls : array_like, mapping or FlightData, optional
        Control samples, shape (n_t, n_controls); required when the model has
        controls (a missing control raises `ChannelError`).
    x0 : array_like or mapping, optional
        Initial state; default zero.
    parameters : mapping or result, optional
        Parameter values merged onto the nominal ones, or a result with ``.parameters``.
    substeps : int
        RK4 steps per sample interval; raise it for coarse sample rates.

    Returns
    -------
    SimulationResult

    Raises
    ------
    AdapterError
        JAX is not installed, the model is a stepped simulator, or its
        dynamics cannot be traced by JAX.
    SimulationError
        The trajectory becomes non-finite (the message names the time).
    """
    from . import jax_compiled as _jax

    m = _jax._check_model(model)
    traced_values = isinstance(parameters, Mapping) and _jax.traced(parameters)
    if traced_values or _jax.traced(x0, controls):
        values = parameters if isinstance(parameters, Mapping) else {}
        if parameters is not None and not isinstance(parameters, Mapping):
            values = resolve_parameters(m, parameters, error=SimulationError)
        t, u, xs, ys = _jax.traced_rollout(
            m, time, controls, x0, dict(values), substeps=substeps, error=SimulationError
        )
        names = (tuple(m.states), m.output_names, tuple(m.controls))
        return _TracedSimulationResult(t, xs, ys, u, *names)
    p = resolve_parameters(m, parameters, error=SimulationError)
    t, u, states, outputs = _jax.rollout(m, time, controls, x0, p, substeps=substeps)
    finite = np.all(np.isfinite(states), axis=1) & np.all(np.isfinite(outputs), axis=1)
    if not finite.all():
        bad = float(t[int(np.argmin(finite))])
        raise SimulationError(
            f"simulation of model {m.name!r} became non-finite at t = {bad:.6g} s"
        )
    return SimulationResult(
        t, states, outputs, u, tuple(m.states), m.output_names, tuple(m.controls)
    )
