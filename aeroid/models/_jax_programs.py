"""The compiled programs of `aeroid.models.compiled`, built once per model structure
(split out of it): the batched RK4 rollout, the tangent-linear sensitivities, a
sampler's outputs, the input-noise scatter and one interval's step and Jacobian."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ._jax_outputs import _outputs_program
from ._jax_rk4 import _input_noise_scatter, _interval, _interval_jacobian, _rollout, _tangent_linear
from ._jax_translation import _entry, _import_jax, _shared, _traced_once

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model


def _compiled(model: Model, kind: str, extra: Any = None) -> Any:
    """The program of `kind` for `model` (`extra`: its variant), compiled on first use."""
    entry = _entry(model)
    cache = _shared(model)
    key = (kind, extra)
    fn = cache.get(key)
    if fn is not None:
        return fn
    mods = _import_jax()
    assert mods is not None
    jax, jnp = mods
    f = _traced_once(entry[("fn", "dynamics")], jax)
    h = entry.get(("fn", "measurement"))
    h = None if h is None else _traced_once(h, jax)
    if kind == "states":
        # one interval a loop iteration, as the sampler's: two compiled a fifth longer and
        # ran no faster, for a batch of one or of many (the demo's rollouts in
        # tests/benchmarks/bench_compilations.py; the same steps, bit for bit)
        roll = _rollout(f, jax, jnp, unroll=1)
        shared_u = bool(extra)
        each = None if shared_u else 0
        fn = jax.jit(jax.vmap(roll, in_axes=(None, each, each, 0, 0, None)))
    elif kind == "sensitivities":
        fn = jax.jit(_tangent_linear(f, h, model, jax, jnp))
    elif kind == "outputs":
        fn = _outputs_program(model, jax, jnp, *extra)
    elif kind == "input_noise":
        fn = jax.jit(_input_noise_scatter(f, h, jax, jnp))
    elif kind == "interval":
        step = _interval(f, jax)
        jacobian = _interval_jacobian(f, jax, jnp)

        def state_jacobian(
            x: Any, t0: Any, t1: Any, u0: Any, u1: Any, e: Any, pvec: Any, m: Any
        ) -> Any:
            return jacobian(x, t0, t1, jnp.zeros(0), lambda _: (pvec, u0, u1, e), m)[0]

        axes = (0, None, None, None, None, None, 0, None)
        pts = jax.vmap(step, in_axes=axes)
        lin = jax.vmap(state_jacobian, in_axes=axes)
        fn = (jax.jit(pts), jax.jit(lin))
    else:  # pragma: no cover - internal
        raise ValueError(kind)
    cache[key] = fn
    return fn
