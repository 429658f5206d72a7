"""The compiled programs of a sampler's batches: parameters to outputs in one call.

Split out of `aeroid.models.compiled` (whose `rk4_outputs` runs them): a batch of
parameter rows rolled out by RK4 from one initial state on one record, the outputs
picked and each member's finiteness checked in the program.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ._jax_rk4 import _rollout
from ._jax_translation import _entry

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model

# `_outputs_program`'s kinds where the stiffness rule picks the substeps in the program:
# the one-substep rollout returning the rule's count with its outputs, and the rule alone
_RULED = -1
_RULE_ONLY = -2
# One interval per loop iteration: each iteration steps a batch of members, so the loop's
# own overhead is a small share of it, and unrolled intervals only lengthen the compilation
# that a cold sampler pays (tests/benchmarks/bench_infer_stage.py, its first call's CPU)
_UNROLL = 1


def _outputs_program(model: Model, jax: Any, jnp: Any, static: int, index: Any) -> Any:
    """``(time, u, e, X, P, m) -> (outputs[:, :, index], ok)`` of a batch (`rk4_outputs`;
    `e` the controls' excess over straight lines, `_integrate.control_excess`):
    `static` substeps written in, 0 for `m`'s. `_RULED`: the one-substep program, which
    also returns the count the stiffness rule picks, ``(outputs, ok, m)`` (its caller
    runs the `m` program where that is not one); `_RULE_ONLY`: ``m`` alone."""
    from .jax_compiled import _substeps_rule

    entry = _entry(model)
    # each traced once, however often the steps call them: tracing the program is most of
    # its cost where the compiled program comes from the disk cache
    f = jax.jit(entry[("fn", "dynamics")])
    if static == _RULE_ONLY:
        rule = _substeps_rule(f, jax, jnp)
        return jax.jit(lambda time, u, e, X, P, m: rule(time, u, X, P))
    h = entry.get(("fn", "measurement"))
    h = None if h is None else jax.jit(h)
    pick = np.asarray(index, dtype=np.int64)
    states_out = None if h is not None else [model.states.index(o) for o in model.output_names]

    def batch_of(roll: Callable[..., Any]) -> Callable[..., Any]:
        def member(time: Any, u: Any, e: Any, x0: Any, pvec: Any, m: Any) -> tuple[Any, Any]:
            xs = roll(time, u, e, x0, pvec, m)
            if h is None:
                ys = xs[:, states_out]
            else:
                ys = jax.vmap(lambda t, x, uk: h(t, x, uk, pvec))(time, xs, u)
            ok = jnp.all(jnp.isfinite(xs)) & jnp.all(jnp.isfinite(ys))
            return ys[:, pick], ok

        return jax.vmap(member, in_axes=(None, None, None, 0, 0, None))

    if static > 0:
        return jax.jit(batch_of(_rollout(f, jax, jnp, static, unroll=_UNROLL)))
    if static == 0:
        return jax.jit(batch_of(_rollout(f, jax, jnp, unroll=_UNROLL)))
    # Only the one-substep rollout in the program, not both behind a condition: the
    # stiffness rule rarely asks for more, and the looped rollout doubled the compilation
    single = batch_of(_rollout(f, jax, jnp, 1, unroll=_UNROLL))
    rule = _substeps_rule(f, jax, jnp)

    def ruled(time: Any, u: Any, e: Any, X: Any, P: Any, m: Any) -> Any:
        return (*single(time, u, e, X, P, m), rule(time, u, X, P))

    return jax.jit(ruled)
