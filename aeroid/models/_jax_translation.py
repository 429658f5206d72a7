"""Numpy-written model functions translated to jax.numpy and checked against the originals.

A copy of a dynamics or measurement function whose module globals and closure
cells bind numpy to `jax.numpy` is traced by JAX; numbers a closure holds are
lifted out so that one compilation serves every model of the same structure,
and each translation is compared with the numpy function once per model
(`_verified`) before `aeroid.models.compiled` uses it.
"""

from __future__ import annotations

import types
import warnings
import weakref
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._threads import in_background, quiet_warnings, user_stacklevel

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model

FloatArray = NDArray[np.float64]


_VERIFY_RTOL = 1e-12


_VERIFY_POINTS = 8


_CACHE: weakref.WeakKeyDictionary[Model, dict[Any, Any]] = weakref.WeakKeyDictionary()


def _entry(model: Model) -> dict[Any, Any]:
    entry = _CACHE.get(model)
    if entry is None:
        entry = {"numpy_calls": 0}
        _CACHE[model] = entry
    return entry


def _import_jax() -> tuple[Any, Any] | None:
    """``(jax, jax.numpy)`` as `aeroid.models.jax_compiled.require_jax` sets it up, or None when JAX
    cannot be imported."""
    from ..errors import AdapterError
    from .jax_compiled import require_jax

    try:
        return require_jax()
    except AdapterError:
        return None


def _traced_once(fn: Callable[..., Any], jax: Any) -> Callable[..., Any]:
    """`fn` as a function JAX traces once per argument shape, however often a program
    calls it (the RK4 steps call the dynamics four times a substep): tracing the model
    is most of a program's cost where its compilation comes from the disk cache, and
    the compiler inlines the call, so the program computes the same."""
    return jax.jit(fn)


# -- translation of a numpy function to jax.numpy ----------------------------------------


def _swap(value: Any, jnp: Any, seen: dict[int, Any], depth: int) -> Any:
    if value is np:
        return jnp
    if isinstance(value, types.FunctionType) and depth < 4:
        return _translate(value, jnp, seen, depth + 1)
    return value


def _translate(fun: Any, jnp: Any, seen: dict[int, Any] | None = None, depth: int = 0) -> Any:
    """A copy of `fun` that sees `jax.numpy` wherever it saw the numpy module.

    Module globals, closure cells and defaults are rebound; helper functions
    reached through them are translated the same way (a few levels deep).
    Anything that is not a plain Python function is returned unchanged.
    """
    if not isinstance(fun, types.FunctionType):
        return fun
    seen = {} if seen is None else seen
    if id(fun) in seen:
        return seen[id(fun)]
    glb: dict[str, Any] = dict(fun.__globals__)
    new = types.FunctionType(fun.__code__, glb, fun.__name__, None, fun.__closure__)
    seen[id(fun)] = new  # before recursing: recursive helpers end here
    names = set(fun.__code__.co_names)
    for name in names & set(glb):
        glb[name] = _swap(glb[name], jnp, seen, depth)
    closure = None
    if fun.__closure__ is not None:
        cells = []
        for cell in fun.__closure__:
            try:
                contents = cell.cell_contents
            except ValueError:  # an empty cell: keep it
                cells.append(cell)
                continue
            cells.append(types.CellType(_swap(contents, jnp, seen, depth)))
        closure = tuple(cells)
    defaults = (
        None
        if fun.__defaults__ is None
        else tuple(_swap(d, jnp, seen, depth) for d in fun.__defaults__)
    )
    final = types.FunctionType(fun.__code__, glb, fun.__name__, defaults, closure)
    final.__kwdefaults__ = fun.__kwdefaults__
    seen[id(fun)] = final
    # Recursive references resolved to the placeholder: point them at the final copy.
    for name in names & set(glb):
        if glb[name] is new:
            glb[name] = final
    return final


# -- closure constants as arguments ------------------------------------------------------
#
# Models built by one factory (an aircraft model per flight condition, a user's
# function closing over numbers) differ only in the numbers their functions close
# over. Those numbers are lifted out of the closures and passed at run time, after
# the model parameters in the parameter vector (`_pmatrix`), so that one compilation
# serves every model of the same structure: the same code, the same non-numeric
# closure contents (term lists, flags, counts), the same names.

_SHARED: dict[Any, dict[Any, Any]] = {}


_SHARED_LIMIT = 16  # structures kept compiled (each holds its XLA executables)


_NUMBER = (float, np.floating)


class _Slot:
    """Where a lifted number goes: its index among the model's constants."""

    __slots__ = ("index",)

    def __init__(self, index: int) -> None:
        self.index = index


def _frozen(value: Any) -> Any:
    """A hashable stand-in for a closure's non-numeric contents; raises TypeError when
    there is none (the model then compiles on its own)."""
    if value is None or isinstance(value, (bool, int, str, bytes, np.integer, np.bool_)):
        return (type(value).__name__, value)
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, tuple(_frozen(v) for v in value))
    if isinstance(value, Mapping):
        return ("map", tuple((_frozen(k), _frozen(v)) for k, v in value.items()))
    if value is np or isinstance(value, types.ModuleType):
        return ("module", value.__name__)
    raise TypeError(type(value).__name__)


class _Template:
    """A function whose closure holds `_Slot`s (and templates) in place of numbers."""

    __slots__ = ("cells", "fun")

    def __init__(self, fun: Any, cells: tuple[Any, ...]) -> None:
        self.fun = fun
        self.cells = cells

    def bind(self, values: Any) -> Any:
        """The plain function, its numbers taken from `values` (traced at run time)."""
        closure = []
        for cell in self.cells:
            if isinstance(cell, _Slot):
                closure.append(types.CellType(values[cell.index]))
            elif isinstance(cell, _Template):
                closure.append(types.CellType(cell.bind(values)))
            else:
                closure.append(types.CellType(cell))
        fun = self.fun
        return types.FunctionType(
            fun.__code__, fun.__globals__, fun.__name__, None, tuple(closure) or None
        )


def _lift(fun: Any, consts: list[float], depth: int = 0) -> tuple[Any, _Template]:
    """``(key, template)`` of a plain function: numbers in its closure (and in the
    closures of functions it closes over) become `_Slot`s appended to `consts`.
    TypeError when something in it has no value-based key."""
    if not isinstance(fun, types.FunctionType) or depth > 4:
        raise TypeError("not a plain function")
    if fun.__defaults__ or fun.__kwdefaults__:
        raise TypeError("defaults")
    cells: list[Any] = []
    keys: list[Any] = []
    for cell in fun.__closure__ or ():
        try:
            value = cell.cell_contents
        except ValueError:
            raise TypeError("empty cell") from None
        if isinstance(value, _NUMBER) and not isinstance(value, bool):
            cells.append(_Slot(len(consts)))
            consts.append(float(value))
            keys.append("number")
        elif isinstance(value, types.FunctionType):
            key, template = _lift(value, consts, depth + 1)
            cells.append(template)
            keys.append(key)
        else:
            cells.append(value)
            keys.append(_frozen(value))
    return (fun.__code__, id(fun.__globals__), tuple(keys)), _Template(fun, tuple(cells))


def _structure(model: Model) -> dict[str, Any]:
    """The model's lifted form, once: its shared-compilation key (None when its functions
    do not lift) and its constants, appended to every parameter vector."""
    entry = _entry(model)
    lifted = entry.get("lifted")
    if lifted is not None:
        return lifted
    consts: list[float] = []
    try:
        dyn = _lift(model._dynamics_batch.fun, consts)
        meas = None if model.measurement is None else _lift(model.measurement, consts)
        key: Any = (
            dyn[0],
            None if meas is None else meas[0],
            tuple(model.states),
            tuple(model.controls),
            tuple(model.parameter_names),
            tuple(model.output_names),
        )
        hash(key)
    except TypeError:
        key, dyn, meas, consts = None, None, None, []
    lifted = {
        "key": key,
        "templates": {"dynamics": dyn and dyn[1], "measurement": meas and meas[1]},
        "consts": np.asarray(consts, dtype=np.float64),
    }
    entry["lifted"] = lifted
    return lifted


def _shared_cache(key: Any) -> dict[Any, Any]:
    cache = _SHARED.get(key)
    if cache is None:
        if len(_SHARED) >= _SHARED_LIMIT:  # oldest first: a long session of new structures
            _SHARED.pop(next(iter(_SHARED)))
        cache = _SHARED[key] = {}
    return cache


def _shared(model: Model) -> dict[Any, Any]:
    """The cache of compiled functions of every model of this one's structure (its own
    cache when its functions did not lift)."""
    entry = _entry(model)
    if not entry.get("lifted_ok"):
        return entry
    return _shared_cache(entry["lifted"]["key"])


def _single(
    bind: Callable[[Any], Any], n_out: int, names: tuple[str, ...], jnp: Any
) -> Callable[..., Any]:
    """``g(t, x, u, pvec) -> (n_out,)`` calling the translated user function on one
    point; ``bind(constants)`` gives that function for the lifted constants that follow
    the model parameters in `pvec` (a plain translation ignores them)."""
    n_p = len(names)

    def g(t: Any, x: Any, u: Any, pvec: Any) -> Any:
        fun = bind(pvec[n_p:])
        p = {n: pvec[i] for i, n in enumerate(names)}
        return jnp.reshape(jnp.asarray(fun(t, x, u, p), dtype=jnp.float64), (n_out,))

    g.bind = bind  # type: ignore[attr-defined]  # for `_dynamic_parameters`
    return g


def _dynamic_parameters(model: Model, time: FloatArray, x: FloatArray, u: FloatArray) -> Any:
    """Positions (in model parameter order) of the parameters the dynamics read.

    Read off the traced dynamics: a parameter that no operation takes in
    cannot move the states, so its sensitivity needs no propagation through
    the rollout (a sensor offset or scale factor of the measurement). Every
    parameter counts as read when the trace cannot tell.
    """
    entry = _entry(model)
    got = entry.get("dynamic_parameters")
    if got is not None:
        return got
    names = model.parameter_names
    every = np.arange(len(names))
    got = every
    mods = _import_jax()
    if mods is not None:
        jax, _ = mods
        try:
            fun = entry[("fn", "dynamics")].bind(_structure(model)["consts"])

            def probe(t: Any, x: Any, u: Any, *ps: Any) -> Any:
                return fun(t, x, u, dict(zip(names, ps, strict=True)))

            jaxpr = jax.make_jaxpr(probe)(float(time[0]), x, u[0], *np.zeros(len(names))).jaxpr
            read = {id(v) for eqn in jaxpr.eqns for v in eqn.invars}
            read |= {id(v) for v in jaxpr.outvars}
            got = np.array(
                [i for i, v in enumerate(jaxpr.invars[3:]) if id(v) in read], dtype=np.int64
            )
        except Exception:  # untraceable here: differentiate by every parameter
            got = every
    entry["dynamic_parameters"] = got
    return got


def _reference(
    fun: Any,
    n_out: int,
    names: tuple[str, ...],
    t: FloatArray,
    X: FloatArray,
    U: FloatArray,
    P: FloatArray,
) -> FloatArray | None:
    """The numpy function point by point (its meaning, whatever it does with arrays)."""
    out = np.empty((t.size, n_out))
    with quiet_warnings(), np.errstate(all="ignore"):
        for i in range(t.size):
            p = {n: float(P[i, j]) for j, n in enumerate(names)}
            try:
                val = np.asarray(fun(float(t[i]), X[i].copy(), U[i].copy(), p), dtype=np.float64)
            except Exception:
                return None
            if val.size != n_out:
                return None
            out[i] = val.reshape(n_out)
    return out


def _verified(
    model: Model,
    role: str,
    time: FloatArray,
    x_ref: FloatArray,
    u: FloatArray,
    pvec: FloatArray,
) -> Callable[..., Any] | None:
    """The single-point jax version of the model's `role` function, or None (numpy only).

    Decided once per model: traced and compared with the numpy function at
    random points spread around `x_ref` (n_x,), the controls `u` (n_t, n_u)
    and the parameters `pvec` (model parameters first, as `_pmatrix` builds
    it). The version with the closure's numbers lifted out (shared by every
    model of the same structure) is tried first, then the plain translation.
    """
    entry = _entry(model)
    key = ("fn", role)
    if key in entry:
        return entry[key]
    entry[key] = None
    got = _first_verification(model, role, (time, x_ref, u, pvec))
    if got is None:
        _untraceable_jax(model, role)
    return got


def _first_verification(
    model: Model, role: str, where: tuple[FloatArray, FloatArray, FloatArray, FloatArray]
) -> Callable[..., Any] | None:
    """`_verified`'s work, done once per model and role, at `where`: its time, x_ref,
    u and pvec."""
    time, x_ref, u, pvec = where
    entry = _entry(model)
    key = ("fn", role)
    mods = _import_jax()
    if mods is None:
        return None
    jax, jnp = mods
    fun = model._dynamics_batch.fun if role == "dynamics" else model.measurement
    if fun is None:
        return None
    n_out = model.n_states if role == "dynamics" else model.n_outputs
    names = model.parameter_names
    n_p = len(names)
    rng = np.random.default_rng(20240611)
    k = _VERIFY_POINTS
    n_t = time.size
    rows = rng.integers(0, n_t, size=k)
    t = time[rows] + rng.uniform(0.0, 1.0, size=k) * (time[-1] - time[0]) / max(n_t - 1, 1)
    X = x_ref[None, :] * (1.0 + 0.05 * rng.standard_normal((k, x_ref.size)))
    X = X + 0.05 * rng.standard_normal((k, x_ref.size))
    U = u[rows] if u.shape[1] else np.zeros((k, 0))
    P = pvec[None, :n_p] * (1.0 + 0.01 * rng.standard_normal((k, n_p)))
    ref = _reference(fun, n_out, names, t, X, U, P)
    if ref is None:
        return None
    lifted = _structure(model)
    for lift in (True, False) if lifted["key"] is not None else (False,):
        if lift:
            cache = _shared_cache(lifted["key"])
            g = cache.get(key)
            if g is None:
                template: _Template = lifted["templates"][role]

                def bound(consts: Any, template: _Template = template) -> Any:
                    return _translate(template.bind(consts), jnp)

                g = cache[key] = _single(bound, n_out, names, jnp)
                cache[("check", role)] = jax.jit(jax.vmap(g))
            check = cache[("check", role)]
            args = np.concatenate(
                [P, np.broadcast_to(lifted["consts"], (k, lifted["consts"].size))], axis=1
            )
        else:
            plain = _translate(fun, jnp)

            def baked(consts: Any, plain: Any = plain) -> Any:
                return plain  # the numbers stay in the closure

            g = _single(baked, n_out, names, jnp)
            check = jax.jit(jax.vmap(g))
            args = P
        if _agrees(check, t, X, U, args, ref):
            entry[("lifted", role)] = lift
            # shared compilations once every function the model has took the lifted form
            entry["lifted_ok"] = entry.get(("lifted", "dynamics"), False) and (
                model.measurement is None or entry.get(("lifted", "measurement"), True)
            )
            entry[key] = g
            return g
    return None


def _untraceable_jax(model: Model, role: str) -> None:
    """Say so when a function written in jax.numpy does not trace: numpy's loops then
    run it point by point through JAX's dispatcher, each call many times the cost of
    the same function written with numpy (or traced, with ``jnp.where``)."""
    batch = model._dynamics_batch if role == "dynamics" else model._measurement_batch
    if batch is None or not batch.jax_written or in_background():
        return
    warnings.warn(
        f"the {role} function of model {model.name!r} is written with jax.numpy, but JAX "
        "cannot trace it (a Python `if` or float() on a state?): it runs on numpy values "
        "one point at a time through JAX's dispatcher, many times slower than the same "
        "function in numpy, or traceable with jnp.where",
        UserWarning,
        stacklevel=user_stacklevel(),
    )


def _agrees(
    check: Callable[..., Any],
    t: FloatArray,
    X: FloatArray,
    U: FloatArray,
    P: FloatArray,
    ref: FloatArray,
) -> bool:
    """Whether the compiled single-point function agrees with the numpy reference."""
    try:
        with quiet_warnings():
            got = np.asarray(check(t, X, U, P), dtype=np.float64)
    except Exception:  # a function JAX cannot trace keeps the numpy path
        return False
    if got.shape != ref.shape:
        return False
    same_nan = np.isnan(got) == np.isnan(ref)
    fin = np.isfinite(ref) & np.isfinite(got)
    scale = np.max(np.where(fin, np.abs(ref), 0.0), axis=0, keepdims=True)
    close = np.abs(got - ref) <= _VERIFY_RTOL * (np.abs(ref) + scale) + 1e-300
    agree = np.where(fin, close, same_nan & ((got == ref) | np.isnan(ref)))
    return bool(np.all(agree))
