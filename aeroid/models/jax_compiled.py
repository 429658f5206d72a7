"""JAX machinery: a jit-compiled, differentiable fixed-step RK4 rollout of a `Model`.

The rollout follows the numpy RK4 of `aeroid.models.integration` step for step
(``substeps`` classical RK4 steps per grid interval, controls straight or cubic
between samples, ``control_interpolation``, evaluated at the RK4 nodes: the program
takes their excess over straight lines, `control_excess`, zero for straight lines),
but is traced once by JAX so that it can
be jit-compiled, vmapped over parameter vectors and differentiated with
respect to the parameters in forward mode.

The user's dynamics (and measurement) function is called with ``x`` and ``u``
as 1-D JAX arrays and ``p`` a dict of JAX scalars, so it must be written with
`jax.numpy` (a function written with plain numpy operators on ``x``, ``u`` and
``p`` works too, as long as it does not build arrays with ``np.array``).

Nothing here is imported by ``import aeroid``; JAX is imported on first use
and 64-bit floats are switched on then.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import platform
import sys
import weakref
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .. import _threads
from ..errors import AdapterError
from ._jax_rk4 import _node
from .integration import Interpolation, check_control_interpolation, control_excess, substeps_for

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model

__all__ = [
    "batch_outputs",
    "outputs_and_jacobian",
    "require_jax",
    "rollout",
    "traced",
    "traced_rollout",
]

FloatArray = NDArray[np.float64]

# One entry per model (weakly held): compiled functions and chosen substeps.
_CACHE: weakref.WeakKeyDictionary[Model, dict[Any, Any]] = weakref.WeakKeyDictionary()


# Where compiled programs are kept between processes: a path, or "off".
CACHE_ENV = "AEROID_JAX_CACHE"
# Bound on that cache's size on disk; JAX drops the least recently used programs beyond.
_CACHE_BYTES = 1 << 30
# the shortest compilation worth a file in the persistent cache
_CACHE_MIN_SECONDS = 0.2
_CONFIGURED = False


def preload_jax() -> None:
    """Import JAX, if installed and not yet imported, alone (`aeroid._threads.alone`):
    while a thread imports it a half-made `jax` sits in ``sys.modules``, and SciPy's
    array checks in another thread's call (`savgol_filter`) read ``jax.Array`` from it
    and fail."""
    if "jax" in sys.modules or importlib.util.find_spec("jax") is None:
        return
    with _threads.alone(), contextlib.suppress(AdapterError):
        require_jax()


def require_jax() -> tuple[Any, Any]:
    """Import JAX with 64-bit floats enabled; return ``(jax, jax.numpy)``."""
    try:
        import jax
        import jax.numpy as jnp
    except ImportError:
        raise AdapterError(
            'the JAX backend needs jax, which is not installed: pip install "aeroid[jax]"'
        ) from None
    global _CONFIGURED
    if not _CONFIGURED:
        _CONFIGURED = True
        folder = _persistent_cache(jax)
        if folder is not None:
            _share_compilations(folder)
    if not jax.config.read("jax_enable_x64"):
        jax.config.update("jax_enable_x64", True)
    return jax, jnp


def _persistent_cache(jax: Any) -> Path | None:
    """Keep XLA's compiled programs on disk (JAX's persistent compilation cache), so a
    fresh process reuses them instead of compiling for seconds at its first fit; returns
    the folder, or None where this left the cache alone.

    Left alone when the user configured a cache of their own (``JAX_COMPILATION_CACHE_DIR``
    or ``jax.config``) or set ``AEROID_JAX_CACHE=off``; ``AEROID_JAX_CACHE=<path>`` picks
    the folder. The default is a per-user folder under the user's cache directory, one
    per CPU kind, since XLA refuses programs compiled for other CPU features. A
    compiled program is code JAX runs, so a folder that other users may write to is
    never used.
    """
    if getattr(jax.config, "jax_compilation_cache_dir", None):
        return None
    choice = os.environ.get(CACHE_ENV, "").strip()
    if choice.lower() in {"off", "0", "false", "no", "none"}:
        return None
    path = Path(choice).expanduser() if choice else _default_cache_dir()
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        info = path.stat()
    except OSError:
        return None
    if info.st_mode & 0o022 or (hasattr(os, "getuid") and info.st_uid != os.getuid()):
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    # JAX keeps only programs that took a second to compile; a fit's smaller programs
    # (filters, short scans: tenths of a second each) add up to seconds a process
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", _CACHE_MIN_SECONDS)
    # JAX bounds the cache only with filelock installed, and without it drops the cache
    # altogether when a bound is set
    if getattr(jax.config, "jax_compilation_cache_max_size", 0) == -1 and _has_filelock():
        jax.config.update("jax_compilation_cache_max_size", _CACHE_BYTES)
    return path


# JAX's function that compiles a program missing from the persistent cache and writes it
# there, and the one that reads the cache (`_share_compilations` wraps the first)
_COMPILE_AND_WRITE = "_compile_and_write_cache"
_CACHE_READ = "_cache_read"


def _share_compilations(folder: Path) -> None:
    """Processes sharing `folder` compile each program once: a process about to compile a
    program another is compiling waits for it and reads its result from the cache.

    The workers of a campaign start on flights of the same model together and meet each
    program at the same moment, when none is on disk yet. A compilation holds an
    advisory lock named by the program's cache key (released by the system if the
    process dies); a process that finds it held waits, then reads the cache, and
    compiles only where the program is still missing (one too quick to compile for the
    cache to keep). Without POSIX file locks, or with a JAX whose internals differ,
    each process compiles on its own.
    """
    try:
        import fcntl  # noqa: F401  (POSIX only)

        from jax._src import compiler
    except ImportError:
        return
    compile_and_write = getattr(compiler, _COMPILE_AND_WRITE, None)
    read = getattr(compiler, _CACHE_READ, None)
    if not callable(compile_and_write) or not callable(read):
        return
    import inspect

    try:  # the arguments this wrapper passes them
        if len(inspect.signature(compile_and_write).parameters) != 7:
            return
        if len(inspect.signature(read).parameters) != 5:
            return
    except (TypeError, ValueError):
        return
    if getattr(compile_and_write, "_aeroid_shared", False):
        return
    locks = folder / "compiling"
    try:
        locks.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        return
    shared = _compile_once(compile_and_write, read, locks)
    shared._aeroid_shared = True  # type: ignore[attr-defined]
    setattr(compiler, _COMPILE_AND_WRITE, shared)


def _compile_once(
    compile_and_write: Callable[..., Any], read: Callable[..., Any], locks: Path
) -> Callable[..., Any]:
    """`compile_and_write` (JAX's ``_compile_and_write_cache``) under a lock per cache key
    in `locks`; a caller that had to wait for the lock first tries `read` (JAX's
    ``_cache_read``)."""
    import fcntl

    def compile_once(
        backend: Any,
        computation: Any,
        devices: Any,
        options: Any,
        callbacks: Any,
        module_name: str,
        cache_key: str,
    ) -> Any:
        def compile_here() -> Any:
            return compile_and_write(
                backend, computation, devices, options, callbacks, module_name, cache_key
            )

        if callbacks:  # JAX keeps no program with host callbacks: nothing to wait for
            return compile_here()
        path = locks / _lock_name(cache_key)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError:
            return compile_here()
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # another process (or thread) compiles it now: wait for it
                fcntl.flock(fd, fcntl.LOCK_EX)
                found, _ = read(module_name, cache_key, options, backend, devices)
                if found is not None:
                    return found
            program = compile_here()
            # no lock files pile up: a process arriving from now on finds the program
            # in the cache (or, too quick to keep, compiles it as before)
            with contextlib.suppress(OSError):
                os.unlink(path)
            return program
        finally:
            os.close(fd)  # releases the lock

    return compile_once


def _lock_name(cache_key: str) -> str:
    """The lock file of a program's cache key (a file name whatever the key holds)."""
    return hashlib.sha256(str(cache_key).encode()).hexdigest()[:32]


def _has_filelock() -> bool:
    try:
        import filelock  # noqa: F401
    except ImportError:
        return False
    return True


def _default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.environ.get("LOCALAPPDATA")
    root = Path(base) if base else Path.home() / ".cache"
    cpu = platform.machine() + platform.processor()
    found: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:  # the first processor's model and feature flags
                key = line.partition(":")[0].strip()
                if key in ("model name", "flags"):
                    found.setdefault(key, line)
                if len(found) == 2:
                    break
    except OSError:
        pass
    cpu += "".join(found.values())
    kind = hashlib.sha256(cpu.encode()).hexdigest()[:12]
    return root / "aeroid" / f"jax-{kind}"


def _check_model(model: Any) -> Model:
    if isinstance(model, Model):
        return model
    name = getattr(model, "name", type(model).__name__)
    raise AdapterError(
        f"model {name!r} is a stepped simulator ({type(model).__name__}) without a continuous "
        "dynamics callable; the JAX paths (simulate_rk4, gradient='jax', backend='jax') need an "
        "aeroid.Model whose dynamics are written with jax.numpy"
    )


# -- the traced rollout ---------------------------------------------------------------


def _traceable(model: Model, fun: Any) -> Any:
    """`fun` (a model's dynamics or measurement) as JAX traces it: as written, or the
    model's own translation where it gives one (the aircraft models of
    `aeroid.models.aircraft`, written with numpy)."""
    translate = getattr(model, "_traced_as_jax", None)
    return fun if fun is None or translate is None else translate(fun)


def _rollout_fn(model: Model, substeps: int) -> Callable[..., Any]:
    """Pure function ``(time, controls, excess, x0, pvec) -> (states, outputs)`` for JAX
    to trace (``excess``: `control_excess` of the controls, (n_t - 1, 2, n_u)).

    Closes over the user's functions only (never the model itself), so the
    weak cache keyed by the model can let it go.
    """
    _, jnp = require_jax()
    import jax

    # a stand-in returning nothing for a model without states
    f = _traceable(model, model._dynamics_batch.fun)
    h = _traceable(model, model.measurement)
    names = model.parameter_names
    n_x = model.n_states
    n_y = model.n_outputs
    out_idx = (
        None if h is not None else np.array([model.states.index(o) for o in model.output_names])
    )
    m = int(substeps)

    def rollout(time: Any, controls: Any, excess: Any, x0: Any, pvec: Any) -> tuple[Any, Any]:
        p = {n: pvec[i] for i, n in enumerate(names)}

        def rhs(t: Any, x: Any, u: Any) -> Any:
            return jnp.reshape(jnp.asarray(f(t, x, u, p), dtype=jnp.float64), (n_x,))

        def interval(x: Any, inp: Any) -> tuple[Any, Any]:
            t0, t1, u0, u1, e = inp
            step = (t1 - t0) / m
            half = 0.5 * step
            du = u1 - u0

            def sub(j: Any, x: Any) -> Any:
                ta = t0 + j * step
                ua = _node(u0, du, e, (2 * j) / (2 * m))
                um = _node(u0, du, e, (2 * j + 1) / (2 * m))
                ub = _node(u0, du, e, (2 * j + 2) / (2 * m))
                k1 = rhs(ta, x, ua)
                k2 = rhs(ta + half, x + half * k1, um)
                k3 = rhs(ta + half, x + half * k2, um)
                k4 = rhs(ta + step, x + step * k3, ub)
                return x + (step / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)

            if m <= 8:  # unrolled: faster to run, still quick to compile
                for j in range(m):
                    x = sub(j, x)
            else:
                x = jax.lax.fori_loop(0, m, sub, x)
            return x, x

        inputs = (time[:-1], time[1:], controls[:-1], controls[1:], excess)
        _, xs = jax.lax.scan(interval, x0, inputs)
        states = jnp.concatenate([x0[None, :], xs], axis=0)
        if h is None:
            outputs = states[:, out_idx]
        else:

            def meas(t: Any, x: Any, u: Any) -> Any:
                return jnp.reshape(jnp.asarray(h(t, x, u, p), dtype=jnp.float64), (n_y,))

            outputs = jax.vmap(meas)(time, states, controls)
        return states, outputs

    return rollout


def _substeps_rule(f: Callable[..., Any], jax: Any, jnp: Any) -> Callable[..., Any]:
    """``(time, u, X (B, n_x), P) -> m``: `aeroid.models.integration.auto_substeps` of a batch
    in the program, `f` the single-point dynamics ``f(t, x, u, pvec)``: the same central
    differences at each member's start, the same eigenvalue rule (`substeps_for`)."""
    from .integration import _MAX_AUTO_SUBSTEPS, substep_demand

    def jacobian(time: Any, u: Any, x0: Any, pvec: Any) -> Any:
        scale = jnp.maximum(jnp.abs(x0), 1.0) * 1e-6
        step = jnp.eye(x0.shape[0]) * scale[None, :]  # row i: scale_i in state i

        def at(x: Any) -> Any:
            return f(time[0], x, u[0], pvec)

        plus = jax.vmap(at)(x0[None, :] + step)
        minus = jax.vmap(at)(x0[None, :] - step)
        return ((plus - minus) / (2.0 * scale[:, None])).T

    def rule(time: Any, u: Any, X: Any, P: Any) -> Any:
        J = jax.vmap(jacobian, in_axes=(None, None, 0, 0))(time, u, X, P)
        finite = jnp.all(jnp.isfinite(J), axis=(1, 2))  # members left out where not
        lam = jnp.linalg.eigvals(jnp.where(finite[:, None, None], J, 0.0))
        size = jnp.abs(lam)
        keep = finite[:, None] & (size > 0)
        size1 = jnp.where(keep, size, 1.0)
        h = jnp.max(jnp.diff(time))
        demand = substep_demand(lam.real, size1, h, time[-1] - time[0], jnp)
        m = jnp.ceil(jnp.max(jnp.where(keep, demand, 0.0)))
        return jnp.clip(m, 1, _MAX_AUTO_SUBSTEPS).astype(jnp.int32)

    return rule


def _entry(model: Model) -> dict[Any, Any]:
    entry = _CACHE.get(model)
    if entry is None:
        entry = {}
        _CACHE[model] = entry
    return entry


def _compiled(model: Model, kind: str, substeps: int) -> Callable[..., Any]:
    """The jitted function of `kind` for this model and substep count (jit caches shapes)."""
    entry = _entry(model)
    key = (kind, substeps)
    fn = entry.get(key)
    if fn is not None:
        return fn
    jax, _ = require_jax()
    roll = _rollout_fn(model, substeps)
    if kind == "rollout":
        fn = jax.jit(roll)
    elif kind == "jacobian":

        def outs(theta: Any, base: Any, idx: Any, time: Any, u: Any, e: Any, x0: Any) -> Any:
            y = roll(time, u, e, x0, base.at[idx].set(theta))[1]
            return y, y

        jac = jax.jacfwd(outs, argnums=0, has_aux=True)

        def both(theta: Any, base: Any, idx: Any, time: Any, u: Any, e: Any, x0: Any) -> Any:
            J, y = jac(theta, base, idx, time, u, e, x0)
            return y, J

        fn = jax.jit(both)
    elif kind == "batch":
        fn = jax.jit(
            jax.vmap(
                lambda time, u, e, x0, pv: roll(time, u, e, x0, pv)[1],
                in_axes=(None, None, None, None, 0),
            )
        )
    else:  # pragma: no cover - internal
        raise ValueError(kind)
    entry[key] = fn
    return fn


# -- argument handling -------------------------------------------------------------------


def _grid(
    model: Model, time: Any, controls: Any, x0: Any, interpolation: Any = "linear"
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Time, controls, initial state and the controls' `control_excess`."""
    from .._checks import check_time

    how = check_control_interpolation(
        interpolation, AdapterError, "control_interpolation", model.controls
    )
    t = check_time(time)
    u = model.control_array(t, controls)
    if u.shape[0] != 1:
        raise AdapterError(
            f"controls: the JAX rollout takes one shared control history of shape "
            f"({t.size}, {model.n_controls}), got shape {u.shape}"
        )
    x = model.initial_state(x0, 1)[0]
    uu = np.ascontiguousarray(u[0])
    return t, uu, x, control_excess(t, uu, how)


def _pvec(model: Model, params: Mapping[str, float]) -> FloatArray:
    unknown = sorted(set(params) - set(model.parameters))
    if unknown:
        raise AdapterError(
            f"parameters {unknown} are not parameters of model {model.name!r}; "
            f"its parameters are {list(model.parameter_names)}"
        )
    return np.array(
        [float(params.get(n, v)) for n, v in model.parameters.items()], dtype=np.float64
    )


def _auto_substeps(
    model: Model, t: FloatArray, u: FloatArray, x0: FloatArray, pv: FloatArray
) -> int:
    """Substeps by the numpy RK4's rule (`_integrate.substeps_for`), cached per grid."""
    h = float(np.max(np.diff(t)))
    entry = _entry(model)
    key = ("substeps", t.size, round(h, 12))
    if key in entry:
        return int(entry[key])
    jax, jnp = require_jax()
    # a stand-in returning nothing for a model without states
    f = _traceable(model, model._dynamics_batch.fun)
    names = model.parameter_names
    n_x = model.n_states

    def rhs(x: Any) -> Any:
        p = {n: pv[i] for i, n in enumerate(names)}
        return jnp.reshape(jnp.asarray(f(float(t[0]), x, jnp.asarray(u[0]), p)), (n_x,))

    try:
        A = np.asarray(jax.jacfwd(rhs)(jnp.asarray(x0)), dtype=np.float64)
    except Exception as exc:
        raise _trace_error(model, exc) from None
    lam = np.linalg.eigvals(A) if np.all(np.isfinite(A)) else np.zeros(0)
    lam = np.asarray(lam, dtype=np.complex128)
    m = substeps_for(lam, h, float(t[-1] - t[0]))
    entry[key] = m
    return m


def _substeps(
    model: Model, substeps: int | None, t: FloatArray, u: FloatArray, x0: FloatArray, pv: FloatArray
) -> int:
    if substeps is None:
        return _auto_substeps(model, t, u, x0, pv)
    return _substep_count(substeps)


def _substep_count(substeps: Any) -> int:
    from ._simulation_checks import check_substeps

    return check_substeps(substeps, "substeps", AdapterError)


def _trace_error(model: Model, exc: Exception) -> AdapterError:
    return AdapterError(
        f"the dynamics/measurement of model {model.name!r} could not be traced by JAX "
        f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}); write them with "
        "jax.numpy (e.g. jnp.array / jnp.stack instead of np.array, no float() of a state)"
    )


def _run(model: Model, fn: Callable[..., Any], *args: Any) -> Any:
    try:
        return fn(*args)
    except AdapterError:
        raise
    except Exception as exc:  # tracing failures surface as many exception types
        raise _trace_error(model, exc) from None


# -- public (package-internal) entry points ------------------------------------------------


def rollout(
    model: Any,
    time: Any,
    controls: Any,
    x0: Any,
    params: Mapping[str, float],
    *,
    substeps: int | None = None,
    control_interpolation: Interpolation | Mapping[str, str] = "linear",
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Run the compiled rollout; returns ``(time, controls, states, outputs)`` as numpy arrays
    (the controls between samples as `control_interpolation` says, as in `Model.simulate`)."""
    model = _check_model(model)
    require_jax()
    t, u, x, e = _grid(model, time, controls, x0, control_interpolation)
    pv = _pvec(model, params)
    m = _substeps(model, substeps, t, u, x, pv)
    states, outputs = _run(model, _compiled(model, "rollout", m), t, u, e, x, pv)
    return t, u, np.asarray(states, dtype=np.float64), np.asarray(outputs, dtype=np.float64)


def traced(*values: Any) -> bool:
    """Whether a caller's JAX transformation (grad, jacfwd, vmap, jit) runs through these
    arguments: one of them, an entry of a mapping or an item of a list, is a tracer."""
    import sys

    core = getattr(sys.modules.get("jax"), "core", None)
    tracer = getattr(core, "Tracer", None)
    if tracer is None:  # JAX never imported: nothing can be traced
        return False
    for v in values:
        items = v.values() if isinstance(v, Mapping) else v if isinstance(v, list | tuple) else (v,)
        if any(isinstance(item, tracer) for item in items):
            return True
    return False


def traced_rollout(
    model: Any,
    time: Any,
    controls: Any,
    x0: Any,
    params: Mapping[str, Any],
    *,
    substeps: int | None,
    error: type[Exception] = AdapterError,
) -> tuple[FloatArray, Any, Any, Any]:
    """The rollout under a caller's JAX transformation: the parameters, the initial state
    and the controls may be tracers, and the states and outputs come back as JAX arrays
    (``(time, controls, states, outputs)``) so that the caller's derivative runs through
    them. The time grid stays concrete; the controls are straight between samples."""
    from .._checks import check_time

    model = _check_model(model)
    _, jnp = require_jax()
    if substeps is None:
        raise AdapterError(
            "substeps: give a count when transforming through the rollout with JAX "
            "(the automatic rule reads the state's values, which a transformation hides)"
        )
    m = _substep_count(substeps)
    t = check_time(time)
    if traced(controls):
        u = _traced_controls(model, controls, t.size, jnp)
        e = jnp.zeros((max(t.size - 1, 0), 2, model.n_controls))
    else:
        _, u, _, e = _grid(model, t, controls, None)
    x = _traced_state(model, x0, jnp, error)
    unknown = sorted(set(params) - set(model.parameters))
    if unknown:
        raise error(
            f"parameters {unknown} are not parameters of model {model.name!r}; "
            f"its parameters are {list(model.parameter_names)}"
        )
    values = [params.get(n, v) for n, v in model.parameters.items()]
    for name, v in zip(model.parameter_names, values, strict=True):
        if jnp.ndim(v) != 0:
            raise error(f"parameter {name!r}: expected a scalar, got shape {jnp.shape(v)}")
    pv = jnp.stack([jnp.asarray(v, dtype=jnp.float64) for v in values])
    states, outputs = _run(model, _compiled(model, "rollout", m), t, u, e, x, pv)
    return t, u, states, outputs


def _traced_controls(model: Model, controls: Any, n_t: int, jnp: Any) -> Any:
    """The control history (n_t, n_controls) from an array or a mapping holding tracers."""
    from ..errors import ChannelError

    if isinstance(controls, Mapping):
        missing = [c for c in model.controls if c not in controls]
        if missing:
            raise ChannelError(
                f"controls: missing {missing}; the model's controls are {list(model.controls)}"
            )
        cols = [
            jnp.broadcast_to(jnp.asarray(controls[c], jnp.float64), (n_t,)) for c in model.controls
        ]
        return jnp.stack(cols, axis=1)
    u = jnp.asarray(controls, dtype=jnp.float64)
    if u.ndim == 1 and model.n_controls == 1:
        u = u[:, None]
    if u.shape != (n_t, model.n_controls):
        raise ChannelError(
            f"controls: expected shape ({n_t}, {model.n_controls}) for the controls "
            f"{list(model.controls)}, got {u.shape}"
        )
    return u


def _traced_state(model: Model, x0: Any, jnp: Any, error: type[Exception]) -> Any:
    """The initial state (n_states,) from None, an array or a mapping, tracers kept."""
    n_x = model.n_states
    if x0 is None:
        return jnp.zeros(n_x)
    if isinstance(x0, Mapping):
        unknown = sorted(set(x0) - set(model.states))
        if unknown:
            raise error(f"x0: unknown states {unknown}; states: {list(model.states)}")
        return jnp.stack([jnp.asarray(x0.get(s, 0.0), jnp.float64) for s in model.states])
    x = jnp.ravel(
        jnp.asarray(jnp.stack(x0) if isinstance(x0, list | tuple) else x0, dtype=jnp.float64)
    )
    if x.shape != (n_x,):
        raise error(f"x0: expected {n_x} values (states {list(model.states)}), got shape {x.shape}")
    return x


def outputs_and_jacobian(
    model: Any,
    time: Any,
    controls: Any,
    x0: Any,
    params: Mapping[str, float],
    names: Any,
    *,
    substeps: int | None = None,
    control_interpolation: Interpolation | Mapping[str, str] = "linear",
) -> tuple[FloatArray, FloatArray]:
    """Outputs (n_t, n_y) and their exact Jacobian (n_t, n_y, len(names)) w.r.t. `names`.

    The Jacobian is the forward-mode derivative (`jax.jacfwd`) of the RK4
    rollout, exact for the discretised trajectory.
    """
    model = _check_model(model)
    require_jax()
    names = tuple(names)
    missing = [n for n in names if n not in model.parameters]
    if missing:
        raise AdapterError(
            f"parameters {missing} are not parameters of model {model.name!r}; "
            f"its parameters are {list(model.parameter_names)}"
        )
    t, u, x, e = _grid(model, time, controls, x0, control_interpolation)
    pv = _pvec(model, params)
    m = _substeps(model, substeps, t, u, x, pv)
    idx = np.array([model.parameter_names.index(n) for n in names], dtype=np.int64)
    y, J = _run(model, _compiled(model, "jacobian", m), pv[idx], pv, idx, t, u, e, x)
    return np.asarray(y, dtype=np.float64), np.asarray(J, dtype=np.float64)


def batch_outputs(
    model: Any,
    time: Any,
    controls: Any,
    x0: Any,
    params_batch: Any,
    *,
    substeps: int | None = None,
    control_interpolation: Interpolation | Mapping[str, str] = "linear",
) -> FloatArray:
    """Outputs (B, n_t, n_y) of a batch of parameter vectors, vmapped in one compiled call.

    `params_batch` is either a mapping name -> (B,) values (missing names take
    their nominal values; scalars broadcast) or an array (B, n_p) in the
    model's parameter order. Diverging members come back with NaN/inf values.
    """
    model = _check_model(model)
    require_jax()
    t, u, x, e = _grid(model, time, controls, x0, control_interpolation)
    names = model.parameter_names
    if isinstance(params_batch, Mapping):
        unknown = sorted(set(params_batch) - set(names))
        if unknown:
            raise AdapterError(
                f"parameters {unknown} are not parameters of model {model.name!r}; "
                f"its parameters are {list(names)}"
            )
        sizes = {np.size(v) for v in params_batch.values() if np.ndim(v) > 0}
        if len(sizes) > 1:
            raise AdapterError(f"params_batch: parameter arrays differ in length {sorted(sizes)}")
        batch = sizes.pop() if sizes else 1
        P = np.stack(
            [
                np.broadcast_to(
                    np.asarray(params_batch.get(n, model.parameters[n]), dtype=np.float64),
                    (batch,),
                )
                for n in names
            ],
            axis=1,
        )
    else:
        P = np.asarray(params_batch, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != len(names):
            raise AdapterError(
                f"params_batch: expected a mapping name -> (B,) or an array (B, {len(names)}) "
                f"in the order {list(names)}, got shape {P.shape}"
            )
    P = np.ascontiguousarray(P)
    m = _substeps(model, substeps, t, u, x, P[0])
    ys = _run(model, _compiled(model, "batch", m), t, u, e, x, P)
    return np.asarray(ys, dtype=np.float64)
