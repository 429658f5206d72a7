"""Compiled simulation of numpy-written models (JAX through the array-API namespace).

A dynamics or measurement function written with plain numpy in the README's
style (``np.array([...])``, ``np.sin``, ``x[0]``, ``alpha, q = x``) is traced
by JAX by calling a copy of it whose module globals (and closure cells) bind
the numpy module to `jax.numpy` instead. The translated function is checked
once per model against the numpy one at random points near the data (agreement
to 1e-12 relative); a function that cannot be traced (a Python ``if`` on a
state, ``float(x[0])``, SciPy calls) or that disagrees keeps the numpy path,
and that decision is remembered per model.

A model's first fit in a process compiles nothing: `_shooting` solves its RK4
rollouts and their sensitivities (and the data-compatibility input-noise
scatter) in numpy by Newton's method over the whole record; the model's next
fit compiles (`output_sensitivities`, `_sensitivities_pay`).

What is compiled:

* a batched (vmapped) fixed-step RK4 rollout that reproduces
  `aeroid._integrate.rk4` step for step (same substeps, same controls linear
  between samples and evaluated at the RK4 nodes), used by `_integrate.integrate`
  through `rk4_hook` once a model has spent more numpy RK4 work than a
  compilation costs;
* outputs and their exact sensitivities with respect to chosen parameters and
  initial states (`output_sensitivities`), used by output error, and the
  first-order effect of white control noise on a fit's gradient
  (`input_noise_scatter`), used by the data-compatibility error bars;
* one sample interval of the RK4 propagation of a batch of points and its
  state Jacobian (`interval_propagator`), for the nonlinear filters.

JAX is imported on first use, never by ``import aeroid``, with 64-bit floats
switched on. Compiled functions are cached per model (weakly held); the
substep count is a run-time argument (one compilation serves every count the
stiffness rule picks) and `jax.jit` caches the shapes, with batches padded to
a power of two so that few shapes occur.
"""

from __future__ import annotations

import types
import warnings
import weakref
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ._integrate import _INSIDE, RawTrajectory, _first_failure

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model

__all__ = [
    "available",
    "input_noise_scatter",
    "interval_propagator",
    "output_sensitivities",
    "rk4_hook",
    "rk4_states",
]

FloatArray = NDArray[np.float64]

# Tests switch this off to force the numpy path.
ENABLED = True
# Numpy RK4 work (dynamics calls, each on a whole batch) a model may spend before the
# integrator hook compiles it: a compilation costs about as much as this many calls.
COMPILE_AFTER_CALLS = 20_000
# The same for a fit's sensitivities, whose compilation (exact Jacobians of the RK4
# steps) costs several times a rollout's: a model's first fit runs in numpy (finite
# differences batched over the parameter columns, step by step) when its expected
# numpy work stays below this (0: compile from the first fit on).
SENSITIVITIES_AFTER_CALLS = 150_000
# RK4 substeps of a record up to which a first fit runs in numpy by Newton's method over
# the record (`_shooting`): its cost grows with the record, a compilation's does not.
SHOOTING_STEPS = 50_000
# Evaluations a fit is expected to spend (Gauss-Newton iterations and step halvings).
_FIT_EVALUATIONS = 8
_VERIFY_RTOL = 1e-12
_VERIFY_POINTS = 8

_CACHE: weakref.WeakKeyDictionary[Model, dict[Any, Any]] = weakref.WeakKeyDictionary()
# The last sensitivities computed: a fit's final evaluation is asked for again by the
# error-bar computations that follow it. Kept only while small.
_LAST_SENSITIVITIES: list[Any] = []
_KEEP_BYTES = 64 * 2**20


def _entry(model: Model) -> dict[Any, Any]:
    entry = _CACHE.get(model)
    if entry is None:
        entry = {"numpy_calls": 0}
        _CACHE[model] = entry
    return entry


def _import_jax() -> tuple[Any, Any] | None:
    """``(jax, jax.numpy)`` as `aeroid._jax.require_jax` sets it up, or None when JAX
    cannot be imported."""
    from ._jax import require_jax
    from .errors import AdapterError

    try:
        return require_jax()
    except AdapterError:
        return None


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
        dyn = _lift(model.dynamics, consts)
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
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
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
    mods = _import_jax()
    if mods is None:
        return None
    jax, jnp = mods
    fun = model.dynamics if role == "dynamics" else model.measurement
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
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
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


def available(
    model: Any,
    time: FloatArray,
    x_ref: FloatArray,
    u: FloatArray,
    pvec: FloatArray,
    *,
    measurement: bool = True,
) -> bool:
    """Whether the model's dynamics (and measurement, if asked) compile and agree."""
    if not ENABLED or not isinstance(model, Model):
        return False
    if _verified(model, "dynamics", time, x_ref, u, pvec) is None:
        return False
    if measurement and model.measurement is not None:
        return _verified(model, "measurement", time, x_ref, u, pvec) is not None
    return True


# -- the RK4 rollout ------------------------------------------------------------------------


def _substep(f: Callable[..., Any], jax: Any) -> Callable[..., Any]:
    """Substep `j` of `m` of one grid interval of RK4, as `_integrate.rk4` computes it."""

    def sub(j: Any, x: Any, t0: Any, t1: Any, u0: Any, u1: Any, pvec: Any, m: Any) -> Any:
        mf = m.astype(x.dtype)
        h = (t1 - t0) / mf
        hh = 0.5 * h
        du = u1 - u0
        inside = _INSIDE * (t1 - t0)
        jf = j.astype(x.dtype)
        ta = t0 + jf * h
        # one-sided ends of the interval, as `_integrate.rk4` evaluates them
        t_first = jax.numpy.where(j == 0, t0 + inside, ta)
        t_last = jax.numpy.where(j == m - 1, t1 - inside, ta + h)
        # (2j)/(2m) etc.: the same correctly rounded fractions as numpy's node grid
        ua = u0 + ((2.0 * jf) / (2.0 * mf)) * du
        um = u0 + ((2.0 * jf + 1.0) / (2.0 * mf)) * du
        ub = u0 + ((2.0 * jf + 2.0) / (2.0 * mf)) * du
        k1 = f(t_first, x, ua, pvec)
        k2 = f(ta + hh, x + hh * k1, um, pvec)
        k3 = f(ta + hh, x + hh * k2, um, pvec)
        k4 = f(t_last, x + h * k3, ub, pvec)
        return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)

    return sub


def _interval(f: Callable[..., Any], jax: Any) -> Callable[..., Any]:
    """One grid interval of RK4 with `m` substeps, as `_integrate.rk4` computes it.

    `m` is an argument (a traced integer), so one compilation serves every
    substep count that the stiffness rule picks as the parameters move.
    """
    sub = _substep(f, jax)

    def step(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, pvec: Any, m: Any) -> Any:
        def body(j: Any, x: Any) -> Any:
            return sub(j, x, t0, t1, u0, u1, pvec, m)

        return jax.lax.fori_loop(0, m, body, x)

    return step


def _interval_jacobian(f: Callable[..., Any], jax: Any, jnp: Any) -> Callable[..., Any]:
    """``(x, t0, t1, z, place, m) -> (phi, gz)``: the Jacobians of one grid interval's
    RK4 step by its start state and by `z`, where ``place(z)`` gives the
    ``(pvec, u0, u1)`` the step uses.

    Substep by substep, each differentiated on its own and the Jacobians chained
    in the loop: differentiating through the loop would trace the model many
    times over (the fixed points that JAX's forward mode and batching of a
    loop iterate), and tracing dominates the compilation of a large model.
    """
    sub = _substep(f, jax)

    def jacobian(
        x: Any, t0: Any, t1: Any, z: Any, place: Callable[[Any], Any], m: Any
    ) -> tuple[Any, Any]:
        def substep(j: Any, xj: Any) -> tuple[Any, Any, Any]:
            def one(xj: Any, z: Any) -> tuple[Any, Any]:
                pvec, u0, u1 = place(z)
                xn = sub(j, xj, t0, t1, u0, u1, pvec, m)
                return xn, xn

            (jx, jz), xn = jax.jacfwd(one, argnums=(0, 1), has_aux=True)(xj, z)
            return xn, jx, jz

        def body(j: Any, carry: tuple[Any, Any, Any]) -> tuple[Any, Any, Any]:
            xj, phi, gz = carry
            xn, jx, jz = substep(j, xj)
            return xn, jx @ phi, jx @ gz + jz

        # the first substep outside the loop: one substep (the usual case) multiplies
        # no Jacobians
        return jax.lax.fori_loop(1, m, body, substep(jnp.int32(0), x))[1:]

    return jacobian


def _rollout(f: Callable[..., Any], jax: Any, jnp: Any) -> Callable[..., Any]:
    """``(time, u (n_t, n_u), x0 (n_x,), pvec, m) -> states (n_t, n_x)``."""
    step = _interval(f, jax)

    def roll(time: Any, u: Any, x0: Any, pvec: Any, m: Any) -> Any:
        def body(x: Any, inp: Any) -> tuple[Any, Any]:
            t0, t1, u0, u1 = inp
            x = step(x, t0, t1, u0, u1, pvec, m)
            return x, x

        # two intervals per loop iteration: the loop's own overhead is a large share of
        # each small step (measured in tests/benchmarks/bench_compatibility.py)
        inputs = (time[:-1], time[1:], u[:-1], u[1:])
        _, xs = jax.lax.scan(body, x0, inputs, unroll=2)
        return jnp.concatenate([x0[None, :], xs], axis=0)

    return roll


def _tangent_linear(
    f: Callable[..., Any], h: Callable[..., Any] | None, model: Model, jax: Any, jnp: Any
) -> Callable[..., Any]:
    """``(theta, pbase, pidx, dpos, xbase, xidx, time, u, m) -> (y, J, states, phi, hx)``.

    Outputs and their Jacobian with respect to ``theta`` (the parameters at
    `pidx`, then the initial states at `xidx`; ``dpos`` marks the parameters
    the dynamics read, `_dynamic_parameters`), with the pieces
    `input_noise_scatter` reuses: the states, each interval's state-transition
    Jacobian ``phi`` and the measurement's state Jacobian ``hx`` per sample.

    Forward mode through the rollout would carry every tangent through every
    step of a sequential loop of small operations. Here the one sequential
    part is a matrix recursion: the Jacobians of each sample interval's RK4
    step are computed for all intervals at once along the primal trajectory,
    then ``S[k+1] = phi[k] S[k] + G[k]`` chains them (the same chain rule in
    another order: equal to rounding).
    """
    interval_jacobian = _interval_jacobian(f, jax, jnp)
    roll = _rollout(f, jax, jnp)
    out_idx = np.array([model.states.index(o) for o in model.output_names]) if h is None else None

    def tl(
        theta: Any,
        pbase: Any,
        pidx: Any,
        dpos: Any,
        xbase: Any,
        xidx: Any,
        time: Any,
        u: Any,
        m: Any,
    ) -> tuple[Any, Any, Any, Any, Any]:
        n_p = pidx.shape[0]
        n_d = dpos.shape[0]  # the parameters (at these positions of theta) the dynamics read
        n_x = xbase.shape[0]
        th = theta[:n_p]
        x0 = xbase.at[xidx].set(theta[n_p:])
        pvec = pbase.at[pidx].set(th)
        xs = roll(time, u, x0, pvec, m)
        pd = pidx[dpos]

        def local(x: Any, t0: Any, t1: Any, u0: Any, u1: Any) -> Any:
            def place(thd: Any) -> tuple[Any, Any, Any]:
                return pvec.at[pd].set(thd), u0, u1

            return interval_jacobian(x, t0, t1, th[dpos], place, m)

        phi, gp = jax.vmap(local)(xs[:-1], time[:-1], time[1:], u[:-1], u[1:])
        forcing = jnp.concatenate([gp, jnp.zeros((phi.shape[0], n_x, xidx.shape[0]))], axis=2)
        s0 = jnp.concatenate([jnp.zeros((n_x, n_d)), jnp.eye(n_x)[:, xidx]], axis=1)

        def chain(s: Any, k: Any) -> tuple[Any, Any]:
            s = k[0] @ s + k[1]
            return s, s

        _, rest = jax.lax.scan(chain, s0, (phi, forcing))
        sx = jnp.concatenate([s0[None], rest], axis=0)  # (n_t, n_x, n_d + n_x0)

        def columns(chained: Any) -> Any:
            # the chained columns in theta's order: dynamic parameters, then initial states
            J = jnp.zeros((*chained.shape[:2], theta.shape[0]))
            return J.at[:, :, dpos].set(chained[:, :, :n_d]).at[:, :, n_p:].set(chained[:, :, n_d:])

        if h is None:
            pick = jnp.eye(n_x)[out_idx]
            hx = jnp.broadcast_to(pick, (time.shape[0], *pick.shape))
            return xs[:, out_idx], columns(sx[:, out_idx, :]), xs, phi, hx

        def meas(t: Any, x: Any, uk: Any) -> Any:
            def g(x: Any, th: Any) -> Any:
                y = h(t, x, uk, pbase.at[pidx].set(th))
                return y, y

            (hx, hp), y = jax.jacfwd(g, argnums=(0, 1), has_aux=True)(x, th)
            return y, hx, hp

        y, hx, hp = jax.vmap(meas)(time, xs, u)
        J = columns(jnp.einsum("kyx,kxc->kyc", hx, sx)).at[:, :, :n_p].add(hp)
        return y, J, xs, phi, hx

    return tl


def _input_noise_scatter(
    f: Callable[..., Any], h: Callable[..., Any] | None, jax: Any, jnp: Any
) -> Callable[..., Any]:
    """``(states, phi, hx, time, u, pvec, m, c, sigma) -> Q``: the covariance of
    ``sum_k c[k]' dy[k]`` when the controls carry white noise of standard
    deviations `sigma` (n_u,) at every sample, dy being the outputs' first-order
    response; ``c`` (n_t, n_y, cols) weights each sample's outputs (a fit's
    ``R^-1 dy/dtheta``), so that Q is the scatter of the Gauss–Newton gradient.

    By the adjoint of the tangent-linear recursion of `_tangent_linear`: one
    backward pass ``lam[k] = hx[k]' c[k] + phi[k]' lam[k+1]`` gives every
    sample's control its effect on the weighted sum, exactly, with no draws.
    """
    interval_jacobian = _interval_jacobian(f, jax, jnp)

    def scatter(
        xs: Any, phi: Any, hx: Any, time: Any, u: Any, pvec: Any, m: Any, c: Any, sigma: Any
    ) -> Any:
        n_u = u.shape[1]

        def local(x: Any, t0: Any, t1: Any, u0: Any, u1: Any) -> Any:
            def place(z: Any) -> tuple[Any, Any, Any]:
                return pvec, z[:n_u], z[n_u:]

            return interval_jacobian(x, t0, t1, jnp.concatenate([u0, u1]), place, m)[1]

        b = jax.vmap(local)(xs[:-1], time[:-1], time[1:], u[:-1], u[1:])
        # products of small matrices per sample, as broadcast sums (one fused loop each)
        g = jnp.sum(hx[:, :, :, None] * c[:, :, None, :], axis=1)  # (n_t, n_x, cols)

        def back(lam: Any, k: Any) -> tuple[Any, Any]:
            lam = k[1] + k[0].T @ lam
            return lam, lam

        _, lams = jax.lax.scan(back, g[-1], (phi, g[:-1]), reverse=True)
        after = jnp.concatenate([lams[1:], g[-1:]], axis=0)  # lam[k + 1] for each interval k
        # a control sample enters the interval it starts and the one it ends
        z0 = jnp.sum(b[:, :, :n_u, None] * after[:, :, None, :], axis=1)
        z1 = jnp.sum(b[:, :, n_u:, None] * after[:, :, None, :], axis=1)
        zero = jnp.zeros_like(z0[:1])
        z = jnp.concatenate([z0, zero], axis=0) + jnp.concatenate([zero, z1], axis=0)
        if h is not None:

            def meas(t: Any, x: Any, uk: Any) -> Any:
                return jax.jacfwd(lambda uk: h(t, x, uk, pvec))(uk)

            hu = jax.vmap(meas)(time, xs, u)
            z = z + jnp.sum(hu[:, :, :, None] * c[:, :, None, :], axis=1)
        flat = (z * sigma[None, :, None]).reshape(-1, c.shape[2])
        return flat.T @ flat

    return scatter


def _compiled(model: Model, kind: str, extra: Any = None) -> Any:
    entry = _entry(model)
    cache = _shared(model)
    key = (kind, extra)
    fn = cache.get(key)
    if fn is not None:
        return fn
    mods = _import_jax()
    assert mods is not None
    jax, jnp = mods
    f = entry[("fn", "dynamics")]
    roll = _rollout(f, jax, jnp)
    if kind == "states":
        shared_u = bool(extra)
        fn = jax.jit(jax.vmap(roll, in_axes=(None, None if shared_u else 0, 0, 0, None)))
    elif kind == "sensitivities":
        fn = jax.jit(_tangent_linear(f, entry.get(("fn", "measurement")), model, jax, jnp))
    elif kind == "input_noise":
        fn = jax.jit(_input_noise_scatter(f, entry.get(("fn", "measurement")), jax, jnp))
    elif kind == "interval":
        step = _interval(f, jax)
        jacobian = _interval_jacobian(f, jax, jnp)

        def state_jacobian(x: Any, t0: Any, t1: Any, u0: Any, u1: Any, pvec: Any, m: Any) -> Any:
            return jacobian(x, t0, t1, jnp.zeros(0), lambda _: (pvec, u0, u1), m)[0]

        axes = (0, None, None, None, None, 0, None)
        pts = jax.vmap(step, in_axes=axes)
        lin = jax.vmap(state_jacobian, in_axes=axes)
        fn = (jax.jit(pts), jax.jit(lin))
    else:  # pragma: no cover - internal
        raise ValueError(kind)
    cache[key] = fn
    return fn


def _pmatrix(model: Model, p: Mapping[str, Any], batch: int) -> FloatArray:
    """Rows of the model parameters (model order), then the model's lifted constants."""
    consts = _structure(model)["consts"]
    columns = [
        np.broadcast_to(np.asarray(p.get(n, v), dtype=np.float64), (batch,))
        for n, v in model.parameters.items()
    ]
    columns += [np.full(batch, c) for c in consts]
    if not columns:  # a model without parameters: rows of nothing
        return np.zeros((batch, 0))
    return np.ascontiguousarray(np.stack(columns, axis=1))


def rk4_states(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
) -> RawTrajectory | None:
    """The compiled RK4 of a batch: x0 (n_x, B), u (B, n_t, n_u), p name -> (B,).

    None when the model's dynamics do not compile (the numpy RK4 then runs).
    """
    if not ENABLED or time.size < 2:
        return None
    batch = x0.shape[1]
    P = _pmatrix(model, p, batch)
    if _verified(model, "dynamics", time, x0[:, 0], u[0], P[0]) is None:
        return None
    if batch == 1:
        known = _last_states(model, time, x0[:, 0], u[0], P[0], substeps)
        if known is not None:
            # the trajectory a fit's last sensitivity pass already rolled out (the
            # result's simulation at the estimate): the same RK4 steps
            ok, fail_time = _first_failure(known[None], time)
            return RawTrajectory(known[None], ok, fail_time)
    shared = batch == 1 or u.strides[0] == 0 or bool(np.all(u == u[:1]))
    fn = _compiled(model, "states", shared)
    # Batches padded to a power of two (copies of the last member): every batch size
    # would otherwise cost a compilation of its own.
    padded = 1 << (batch - 1).bit_length()
    rows = np.minimum(np.arange(padded), batch - 1)
    uu = np.ascontiguousarray(u[0] if shared else u[rows])
    X = np.ascontiguousarray(x0.T[rows])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        states = np.asarray(fn(time, uu, X, P[rows], np.int32(substeps)), dtype=np.float64)
    states = states[:batch]
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


def worth_compiling(model: Model, calls: int) -> bool:
    """Whether compiling `model` pays now, about to spend `calls` more dynamics calls.

    A model compiles once its numpy work (counted here while it does not) reaches
    about what a compilation costs, so one-off simulations and filter passes
    never wait for a compiler; once compiled it always is.
    """
    entry = _entry(model)
    if entry.get("compiled_once"):
        return True
    # the numpy rollouts of fits that `output_sensitivities` kept in numpy do not count
    allowance = COMPILE_AFTER_CALLS + entry.get("sensitivity_numpy_calls", 0)
    if entry["numpy_calls"] + calls <= allowance:
        entry["numpy_calls"] += calls
        return False
    return True


def rk4_hook(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
) -> RawTrajectory | None:
    """`_integrate.integrate`'s RK4 branch: the compiled RK4 once it pays, else None.

    Records the substep count on the model (`output_sensitivities` reads it)
    and counts the numpy work spent, so that a model integrated once or twice
    never waits for a compilation.
    """
    if not ENABLED or not isinstance(model, Model):
        return None
    entry = _entry(model)
    entry["last_substeps"] = int(substeps)
    if entry.get("probing") or entry.get(("fn", "dynamics"), True) is None:
        # a probe only asks which path the integrator takes: no compilation for its
        # two-sample record
        return None  # decided: numpy only
    if x0.shape[1] == 1 and not entry.get("compiled_once"):
        from ._shooting import last_states

        known = last_states(model, time, x0, u, p, substeps)
        if known is not None:
            # the rollout a fit's numpy sensitivities last solved for (the result's
            # simulation at the estimate): the same RK4 steps, to rounding
            ok, fail_time = _first_failure(known[None], time)
            return RawTrajectory(known[None], ok, fail_time)
    if not worth_compiling(model, 4 * int(substeps) * (time.size - 1)):
        return None
    traj = rk4_states(model, time, x0, u, p, substeps)
    if traj is not None:
        entry["compiled_once"] = True
    return traj


# -- output-error sensitivities ----------------------------------------------------------


def output_sensitivities(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    names: Sequence[str],
    x0_free: Sequence[int],
    options: Mapping[str, Any],
    *,
    probe: bool = True,
    numpy_first: bool = False,
) -> tuple[FloatArray, FloatArray] | None:
    """Outputs (n_t, n_y) and their exact Jacobian (n_t, n_y, len(names) + len(x0_free)).

    The columns are the model parameters `names`, then the initial states
    `x0_free`; `params` holds every model parameter. The Jacobian is the
    exact derivative (by the chain rule, see `_tangent_linear`) of the same
    RK4 rollout that `simulate_batch` runs, with the same substeps. None when
    it does not apply: JAX missing, functions that do not compile, or an
    integration other than RK4 (the exact path of linear time-invariant
    models, solve_ivp). With `probe`, one
    plain simulation first asks the integrator which path it takes (the
    caller remembers the answer and passes ``probe=False`` afterwards).
    Outputs of a diverging simulation come back non-finite.

    With `numpy_first` (a fit's first evaluation), None also while compiling would
    not pay yet: the model's first fit in this process, whose expected step-by-step
    numpy work stays below `SENSITIVITIES_AFTER_CALLS`, or whose record has at most
    `SHOOTING_STEPS` RK4 substeps where the dynamics take an array of times (the fit
    then runs `_shooting`'s Newton over the record; `declined` tells the caller). A
    one-off fit then never waits for JAX's import and compiler; a model fitted again
    compiles.
    """
    if not ENABLED or not isinstance(model, Model):
        return None
    if options.get("method", "auto") not in ("auto", "rk4"):
        return None
    pvec = _pmatrix(model, params, 1)[0]
    x0 = np.asarray(x0, dtype=np.float64)
    # pvec carries the lifted constants after the parameters
    p1 = {k: np.array([v]) for k, v in zip(model.parameter_names, pvec, strict=False)}
    if probe:
        # The integrator decides between the exact linear path and RK4; it tells through
        # the hook. Two samples suffice: a model it integrates on them is not linear
        # time-invariant on the whole record either.
        entry = _entry(model)
        entry.pop("last_substeps", None)
        entry["probing"] = True
        try:
            model.simulate_batch(time[:2], controls[:2], x0, p1, **options)
        finally:
            entry.pop("probing", None)
        if entry.pop("last_substeps", None) is None:
            return None
    m = rk4_substeps(model, time, controls, x0, params, options)
    if numpy_first and not _sensitivities_pay(model, m, time.size):
        _entry(model)["declined"] = True
        return None
    if not available(model, time, x0, controls, pvec):
        return None
    got = _sensitivities(model, time, controls, x0, pvec, names, x0_free, m)
    _entry(model)["sensitivities_compiled"] = True
    return got[0], got[1]


def rk4_substeps(
    model: Model,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    options: Mapping[str, Any],
) -> int:
    """The RK4 substeps of one simulation: `options`' ``substeps``, else from the
    stiffness of the dynamics at the start (`_integrate.auto_substeps`)."""
    if options.get("substeps") is not None:
        return int(options["substeps"])
    from ._integrate import auto_substeps

    p1 = {k: np.array([float(params.get(k, v))]) for k, v in model.parameters.items()}
    x = np.asarray(x0, dtype=np.float64)[:, None].copy()
    return auto_substeps(model._dynamics_batch, time, x, np.asarray(controls)[None], p1)


def declined(model: Any) -> bool:
    """Whether `output_sensitivities` just declined to compile `model`'s first fit
    (asked with ``numpy_first``): the fit then runs in numpy."""
    if not isinstance(model, Model):
        return False
    return bool(_entry(model).pop("declined", False))


def _sensitivities_pay(model: Model, substeps: int, n_t: int) -> bool:
    """Whether a fit of `n_t` samples with `substeps` RK4 substeps should compile the
    model's sensitivities now (see `output_sensitivities`); counts the numpy work
    spent when not."""
    entry = _entry(model)
    if entry.get("sensitivities_compiled"):
        return True
    # batched dynamics calls of the fit's rollouts: 4 per substep
    work = _FIT_EVALUATIONS * 4 * int(substeps) * max(n_t - 1, 1)
    spent = entry.get("sensitivity_numpy_calls", 0)
    # only the first fit: a model fitted twice is likely fitted again (warm calls as fast
    # as compiled ones from the second on)
    f = model._dynamics_batch
    # Newton over the record (`_shooting`) makes a few calls of each RK4 stage on every
    # substep at once, for dynamics that take an array of times: far cheaper
    shooting = f.broadcasts is not False and f.time_broadcasts is not False
    steps = int(substeps) * max(n_t - 1, 1)
    # (SENSITIVITIES_AFTER_CALLS = 0 compiles from the first fit on, Newton or not)
    shooting = shooting and steps <= SHOOTING_STEPS and SENSITIVITIES_AFTER_CALLS > 0
    if spent == 0 and (work <= SENSITIVITIES_AFTER_CALLS or shooting):
        entry["sensitivity_numpy_calls"] = spent + work
        return False
    return True


def input_noise_scatter(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    params: Mapping[str, float],
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
    inverse_variances: FloatArray,
    sigma: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """Outputs, their Jacobian (as `output_sensitivities`, RK4 with `substeps`) and
    the covariance of the Gauss–Newton gradient ``sum_k J[k]' R^-1 dy[k]`` that white
    control noise of standard deviations `sigma` (n_u,) causes to first order; R^-1
    is ``diag(inverse_variances)`` over the model outputs (zero for those not fitted).
    None when the model does not compile."""
    if not ENABLED or not isinstance(model, Model) or time.size < 2:
        return None
    if not _entry(model).get("sensitivities_compiled"):
        # a model whose fit ran in numpy: the same adjoint in numpy, no compilation
        from . import _shooting

        got = _shooting.input_noise_scatter(
            model, time, controls, x0, params, names, x0_free, substeps, inverse_variances, sigma
        )
        if got is not None:
            return got
    pvec = _pmatrix(model, params, 1)[0]
    x0 = np.asarray(x0, dtype=np.float64)
    if not available(model, time, x0, controls, pvec):
        return None
    y, J, xs, phi, hx = _sensitivities(model, time, controls, x0, pvec, names, x0_free, substeps)
    cols = J.shape[2]
    # columns padded to a multiple of eight: another set of estimated parameters seldom
    # costs another compilation
    weighted = np.zeros((*J.shape[:2], -(-cols // 8) * 8))
    weighted[:, :, :cols] = J * np.asarray(inverse_variances, dtype=np.float64)[None, :, None]
    fn = _compiled(model, "input_noise")
    u = np.asarray(controls, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scatter = fn(xs, phi, hx, time, u, pvec, np.int32(substeps), weighted, s)
    return y, J, np.asarray(scatter, dtype=np.float64)[:cols, :cols]


def _sensitivities(
    model: Model,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    pvec: FloatArray,
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
) -> tuple[FloatArray, ...]:
    pidx = np.array([model.parameter_names.index(n) for n in names], dtype=np.int64)
    xidx = np.asarray(list(x0_free), dtype=np.int64)
    theta = np.concatenate([pvec[pidx], x0[xidx]])
    u = np.asarray(controls, dtype=np.float64)
    dynamic = _dynamic_parameters(model, time, x0, u)
    dpos = np.flatnonzero(np.isin(pidx, dynamic)).astype(np.int64)
    key = (pvec.tobytes(), x0.tobytes(), tuple(names), tuple(x0_free), int(substeps))
    last = _LAST_SENSITIVITIES
    if (
        last
        and last[0]() is model
        and last[1] == key
        and _same(last[2], time)
        and _same(last[3], u)
    ):
        return last[4]  # the same point again (an error-bar pass after a fit)
    fn = _compiled(model, "sensitivities")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = fn(theta, pvec, pidx, dpos, x0, xidx, time, u, np.int32(substeps))
    out = tuple(np.asarray(a, dtype=np.float64) for a in got)
    for a in out:  # shared with the next caller at the same point: nobody writes to them
        a.flags.writeable = False
    keep = out[1].nbytes <= _KEEP_BYTES
    _LAST_SENSITIVITIES[:] = [weakref.ref(model), key, time, u, out] if keep else []
    return out


def _last_states(
    model: Model, time: FloatArray, x0: FloatArray, u: FloatArray, pvec: FloatArray, substeps: int
) -> FloatArray | None:
    """The states (n_t, n_x) of the last sensitivity pass when it was at this point:
    the same initial state, controls and substeps, and the same values of the
    parameters the dynamics read (a sensor's offset or scale factor may differ)."""
    last = _LAST_SENSITIVITIES
    if not last or last[0]() is not model:
        return None
    key = last[1]
    before = np.frombuffer(key[0])
    read = np.concatenate(
        [
            np.asarray(_dynamic_parameters(model, time, x0, u), dtype=np.int64),
            np.arange(len(model.parameter_names), before.size),  # the lifted constants
        ]
    )
    if (
        before.shape != pvec.shape
        or not np.array_equal(before[read], pvec[read])
        or key[1] != np.ascontiguousarray(x0, dtype=np.float64).tobytes()
        or key[4] != int(substeps)
        or not _same(last[2], time)
        or not _same(last[3], np.asarray(u, dtype=np.float64))
    ):
        return None
    states: FloatArray = last[4][2]
    return states


def _same(a: FloatArray, b: FloatArray) -> bool:
    return a is b or (a.shape == b.shape and bool(np.array_equal(a, b)))


# -- filters: one sample interval ---------------------------------------------------------------


def interval_propagator(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x_ref: FloatArray,
    params: Mapping[str, float],
    substeps: int,
) -> Callable[..., Any] | None:
    """Compiled RK4 propagation over one sample interval, for the nonlinear filters.

    Returns ``propagate(k, X, P, jacobian=False)`` moving points ``X`` (M, n_x)
    with parameter rows ``P`` (M, n_p) (model parameter order) from sample k
    to k+1 of `time` with `controls` (n_t, n_u), exactly as
    `_integrate.rk4` would with `substeps`; with ``jacobian=True`` it returns
    ``(X_next, Phi)`` with ``Phi`` (M, n_x, n_x) the exact state-transition
    Jacobian of the step. None when the dynamics do not compile.
    """
    if not ENABLED or not isinstance(model, Model):
        return None
    pvec = _pmatrix(model, params, 1)[0]
    if _verified(model, "dynamics", time, x_ref, controls, pvec) is None:
        return None
    pts, lin = _compiled(model, "interval")
    m = np.int32(substeps)
    t = np.asarray(time, dtype=np.float64)
    u = np.asarray(controls, dtype=np.float64)

    def propagate(k: int, X: FloatArray, P: FloatArray, jacobian: bool = False) -> Any:
        args = (X, t[k], t[k + 1], u[k], u[k + 1], P, m)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            nxt = np.asarray(pts(*args), dtype=np.float64)
            if not jacobian:
                return nxt
            return nxt, np.asarray(lin(*args), dtype=np.float64)

    return propagate
