"""Compiled simulation of numpy-written models (JAX through the array-API namespace).

A dynamics or measurement function written with plain numpy in the README's
style (``np.array([...])``, ``np.sin``, ``x[0]``, ``alpha, q = x``) is traced
by JAX by calling a copy of it whose module globals (and closure cells) bind
the numpy module to `jax.numpy` instead. The translated function is checked
once per model against the numpy one at random points near the data (agreement
to 1e-12 relative); a function that cannot be traced (a Python ``if`` on a
state, ``float(x[0])``, SciPy calls) or that disagrees keeps the numpy path,
and that decision is remembered per model.

A model's first fit in a process compiles nothing (`_shooting`: Newton's method
over the record in numpy); its next fit compiles (`_sensitivities_pay`).

What is compiled: the batched (vmapped) fixed-step RK4 rollout, step for step
`aeroid.models.integration.rk4`'s (`rk4_hook`, once a model has spent more numpy RK4
work than a compilation costs); a sampler's batch from parameters to outputs, its
substeps decided in the program (`rk4_outputs`); outputs with their exact
sensitivities to chosen parameters and initial states (`output_sensitivities`) and
the first-order effect of white control noise on a fit's gradient
(`input_noise_scatter`); one sample interval of the RK4 propagation of a batch of
points with its state Jacobian (`interval_propagator`, the nonlinear filters).
The path a call takes depends on the model object's history (`fixed_path`).

Every program takes the controls' excess over straight lines per interval (zero for
straight lines: cubic controls run in the same programs). JAX is imported on first
use, never by ``import aeroid``, with 64-bit floats on. Compiled functions are cached
per model (weakly held); the substep count is a run-time argument and `jax.jit`
caches the shapes, batches padded to a power of two so that few shapes occur.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import weakref
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .. import _threads
from .._threads import quiet_warnings
from ._jax_outputs import _RULE_ONLY, _RULED
from ._jax_programs import _compiled
from ._jax_rk4 import _interval as _interval
from ._jax_rk4 import _substep as _substep
from ._jax_translation import _CACHE as _CACHE
from ._jax_translation import _NUMBER as _NUMBER
from ._jax_translation import _SHARED as _SHARED
from ._jax_translation import _SHARED_LIMIT as _SHARED_LIMIT
from ._jax_translation import _VERIFY_POINTS as _VERIFY_POINTS
from ._jax_translation import _VERIFY_RTOL as _VERIFY_RTOL
from ._jax_translation import _agrees as _agrees
from ._jax_translation import (
    _dynamic_parameters,
    _entry,
    _structure,
    _verified,
)
from ._jax_translation import _frozen as _frozen
from ._jax_translation import _import_jax as _import_jax
from ._jax_translation import _lift as _lift
from ._jax_translation import _reference as _reference
from ._jax_translation import _shared as _shared
from ._jax_translation import _shared_cache as _shared_cache
from ._jax_translation import _single as _single
from ._jax_translation import _Slot as _Slot
from ._jax_translation import _swap as _swap
from ._jax_translation import _Template as _Template
from ._jax_translation import _traced_once as _traced_once
from ._jax_translation import _translate as _translate
from .integration import Interpolation, RawTrajectory, _first_failure, control_excess
from .jax_compiled import preload_jax

if TYPE_CHECKING:
    from .model import Model
else:  # below aeroid.models.model (it calls this module): its base class stands in
    from ._model_base import ContinuousModel as Model

__all__ = [
    "available",
    "compiled_rollout",
    "fixed_path",
    "input_noise_scatter",
    "interval_propagator",
    "output_sensitivities",
    "rk4_hook",
    "rk4_outputs",
    "rk4_states",
]

FloatArray = NDArray[np.float64]

_log = logging.getLogger("aeroid")

# Tests switch this off to force the numpy path.
ENABLED = True
# A model whose first fit ran in numpy compiles in the library's background thread
# after it (`aeroid._threads.after_call`); off, its next fit compiles in the foreground.
BACKGROUND = True
_FIXED, _FIXED_LOCK = [0], threading.Lock()  # calls under `fixed_path`
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

# The last sensitivities computed: a fit's final evaluation is asked for again by the
# error-bar computations that follow it. Kept only while small.
_LAST_SENSITIVITIES: list[Any] = []
_KEEP_BYTES = 64 * 2**20


def _background() -> bool:
    return BACKGROUND and not _FIXED[0]


@contextlib.contextmanager
def fixed_path() -> Iterator[None]:
    """Within: a model's later fits compile in the foreground instead of racing a
    background compilation, so the path (numpy or compiled) depends on the calls made
    with the model object only. The pipeline runs each task so, on a fresh copy of its
    model: a result's bits never depend on the worker's history (workers, a rerun)."""
    with _FIXED_LOCK:
        _FIXED[0] += 1
    try:
        yield
    finally:
        with _FIXED_LOCK:
            _FIXED[0] -= 1


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


def _pmatrix(model: Model, p: Mapping[str, Any], batch: int) -> FloatArray:
    """Rows of the model parameters (model order), then the model's lifted constants."""
    consts = _structure(model)["consts"]
    n_p = len(model.parameters)
    P = np.empty((batch, n_p + consts.size))
    # column by column: the values a stack of broadcast columns holds, without building them
    for i, (n, v) in enumerate(model.parameters.items()):
        P[:, i] = np.asarray(p.get(n, v), dtype=np.float64)
    P[:, n_p:] = consts
    return P


def rk4_states(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
    interpolation: Interpolation = "linear",
) -> RawTrajectory | None:
    """The compiled RK4 of a batch: x0 (n_x, B), u (B, n_t, n_u), p name -> (B,), the
    controls between samples as `interpolation` says.

    None when the model's dynamics do not compile (the numpy RK4 then runs).
    """
    if not ENABLED or time.size < 2:
        return None
    batch = x0.shape[1]
    P = _pmatrix(model, p, batch)
    if _verified(model, "dynamics", time, x0[:, 0], u[0], P[0]) is None:
        return None
    if batch == 1:
        known = _last_states(model, time, x0[:, 0], u[0], P[0], substeps, interpolation)
        if known is not None:
            # the trajectory a fit's last sensitivity pass already rolled out (the
            # result's simulation at the estimate): the same RK4 steps
            ok, fail_time = _first_failure(known[None], time)
            return RawTrajectory(known[None], ok, fail_time)
    shared = batch == 1 or u.strides[0] == 0 or bool(np.all(u == u[:1]))
    fn = _compiled(model, "states", shared)
    # Batches padded to a power of two (copies of the last member): every batch size
    # would otherwise cost a compilation of its own.
    rows = padded_rows(batch)
    uu = np.ascontiguousarray(u[0] if shared else u[rows])
    E = control_excess(time, uu, interpolation)
    X = np.ascontiguousarray(x0.T[rows])
    with quiet_warnings():
        states = np.asarray(fn(time, uu, E, X, P[rows], np.int32(substeps)), dtype=np.float64)
    states = states[:batch]
    ok, fail_time = _first_failure(states, time)
    return RawTrajectory(states, ok, fail_time)


def compiled_rollout(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int,
    interpolation: Interpolation = "linear",
) -> RawTrajectory | None:
    """`rk4_states`, asked for by a caller that has decided by its problem's size that
    the compiled rollout pays; the model's later simulations then take it too, as
    they do once `rk4_hook` has compiled it. None where the model does not compile."""
    traj = rk4_states(model, time, x0, u, p, substeps, interpolation)
    if traj is not None:
        _entry(model)["compiled_once"] = True
    return traj


# Substep counts up to which `rk4_outputs` writes the count into its program (no inner
# loop to run); above, one program serves every count.
_STATIC_SUBSTEPS = 2


def _ruled_outputs(model: Model, index: tuple[int, ...], args: tuple[Any, ...]) -> tuple[Any, Any]:
    """`rk4_outputs` with the stiffness rule's substeps: the one-substep program, and the
    looped one only where the rule asks for more (compiled then). A model that did once
    asks the rule first (a program of its own) from then on, so that no batch pays for
    both rollouts again."""
    entry = _entry(model)
    stiff = ("stiff", index)
    if entry.get(stiff):
        m = int(_compiled(model, "outputs", (_RULE_ONLY, ()))(*args))
        if m == 1:
            y, ok, _ = _compiled(model, "outputs", (_RULED, index))(*args)
            return y, ok
    else:
        y, ok, m_rule = _compiled(model, "outputs", (_RULED, index))(*args)
        m = int(m_rule)
        if m == 1:
            return y, ok
        entry[stiff] = True
    looped = _compiled(model, "outputs", (0, index))
    y, ok = looped(*args[:5], np.int32(m))
    return y, ok


def padded_rows(batch: int, pad: int = 0) -> NDArray[np.int_]:
    """The rows a compiled batch of `batch` members runs: the members, then the last one
    repeated up to the next power of two of ``max(batch, pad)`` (few batch sizes, few
    compilations)."""
    padded = 1 << (max(batch, pad) - 1).bit_length()
    return np.minimum(np.arange(padded), batch - 1)


def rk4_outputs(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
    substeps: int | None,
    index: Sequence[int],
    *,
    pad: int = 0,
    interpolation: Interpolation = "linear",
) -> tuple[FloatArray, NDArray[np.bool_]] | None:
    """The outputs at `index` (B, n_t, k) of a compiled RK4 batch and whether each member
    stayed finite (every state and output at every sample): x0 (n_x, B), u (n_t, n_u)
    shared, p name -> (B,). One compiled call from the parameters to the outputs, for
    a caller about to simulate many batches on one record (a sampler): the same RK4
    steps as `rk4_states` and the same measurement, equal to it to rounding; `substeps`
    None: the stiffness rule's (`_integrate.auto_substeps`), applied in the program.
    Batches are padded to a power of two, at least `pad` (the caller's usual batch:
    one compiled program). None when the model does not compile (dynamics and
    measurement)."""
    if not ENABLED or time.size < 2:
        return None
    batch = x0.shape[1]
    P = _pmatrix(model, p, batch)
    if not available(model, time, x0[:, 0], u, P[0]):
        return None
    rows = padded_rows(batch, pad)
    X = np.ascontiguousarray(x0.T[rows])
    E = control_excess(time, u, interpolation)
    return rk4_output_rows(model, time, u, X, P[rows], substeps, index, batch, E)


def rk4_output_rows(
    model: Model,
    time: FloatArray,
    u: FloatArray,
    X: FloatArray,
    P: FloatArray,
    substeps: int | None,
    index: Sequence[int],
    batch: int,
    E: FloatArray,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """`rk4_outputs` of rows already padded: initial states X (padded, n_x) and parameter
    rows P (padded, n_p + constants, `_pmatrix`'s columns), the first `batch` of them
    returned, E the controls' `control_excess`; for a caller that has checked the model
    compiles (`available`) and keeps what stays the same from call to call."""
    key = tuple(int(i) for i in index)
    with quiet_warnings():
        if substeps is None:  # by the stiffness rule, in the program
            y, ok = _ruled_outputs(model, key, (time, u, E, X, P, np.int32(0)))
        else:
            m = int(substeps)
            static = m if m <= _STATIC_SUBSTEPS else 0
            y, ok = _compiled(model, "outputs", (static, key))(time, u, E, X, P, np.int32(m))
        y = np.array(y, dtype=np.float64)[:batch]
    _entry(model)["compiled_once"] = True  # its later simulations take the compiled RK4 too
    return y, np.asarray(ok, dtype=bool)[:batch]


def worth_compiling(model: Model, calls: int) -> bool:
    """Whether compiling `model` pays now, about to spend `calls` more dynamics calls.

    A model compiles once its numpy work (counted here while it does not) reaches
    about what a compilation costs, so one-off simulations and filter passes
    never wait for a compiler; once compiled it always is.
    """
    entry = _entry(model)
    if entry.get("compiled_once") or model._dynamics_batch.jax_written:
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
    interpolation: Interpolation = "linear",
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
    if x0.shape[1] == 1 and not entry.get("compiled_once") and interpolation == "linear":
        # (Newton over the record holds straight lines)
        from .shooting import last_states

        known = last_states(model, time, x0, u, p, substeps)
        if known is not None:
            # the rollout a fit's numpy sensitivities last solved for (the result's
            # simulation at the estimate): the same RK4 steps, to rounding
            ok, fail_time = _first_failure(known[None], time)
            return RawTrajectory(known[None], ok, fail_time)
    if x0.shape[1] == 1 and entry.get("sensitivities_compiled"):
        # the rollout a compiled fit's last sensitivities computed (the result simulated
        # at its estimate, its sensors' errors perhaps zeroed): no numpy stepping for it
        # while the rollouts themselves are not yet worth compiling
        pvec = _pmatrix(model, p, 1)[0]
        known = _last_states(model, time, x0[:, 0], u[0], pvec, substeps, interpolation)
        if known is not None:
            ok, fail_time = _first_failure(known[None], time)
            return RawTrajectory(known[None], ok, fail_time)
    if not worth_compiling(model, 4 * int(substeps) * (time.size - 1)):
        return None
    traj = rk4_states(model, time, x0, u, p, substeps, interpolation)
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
    RK4 rollout that `simulate_batch` runs, with the same substeps and controls
    between samples (``options['control_interpolation']``). None when
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
    if not ENABLED or not isinstance(model, Model) or not model.n_states:
        # (without states the outputs are the measurement at each sample: the caller's
        # central differences of it, batched over the columns, cost less than compiling)
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
    from .integration import check_control_interpolation

    how = check_control_interpolation(
        options.get("control_interpolation", "linear"), controls=model.controls
    )
    if numpy_first and not _sensitivities_pay(model, m, time.size):
        entry = _entry(model)
        entry["declined"] = True
        entry["numpy_fits"] = fits = entry.get("numpy_fits", 0) + 1
        if _background() and fits > 1:
            # a model fitted again is likely fitted once more: compiled in the background
            # once this fit has returned (a one-off fit never starts a compiler), and the
            # next fit switches to the compiled program if it is ready by then
            job = (time, controls, x0, pvec, tuple(names), tuple(x0_free), m, how)
            _queue(model, "sensitivities", *job)
        return None
    if not available(model, time, x0, controls, pvec):
        return None
    got = _sensitivities(model, time, controls, x0, pvec, names, x0_free, m, how)
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
    from .integration import auto_substeps

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
    if entry.get("sensitivities_compiled") or model._dynamics_batch.jax_written:
        return True
    # batched dynamics calls of the fit's rollouts: 4 per substep
    work = _FIT_EVALUATIONS * 4 * int(substeps) * max(n_t - 1, 1)
    spent = entry.get("sensitivity_numpy_calls", 0)
    state = entry.get(("background", "sensitivities"))
    if state == "ready":
        return True
    if _background() and spent > 0:
        # fitted in numpy before: this fit too, while the background thread compiles
        # (`output_sensitivities` queues it; for good where that failed), its rollouts
        # not counted towards compiling them (`worth_compiling`)
        entry["sensitivity_numpy_calls"] = spent + work
        return False
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


def _queue(model: Model, program: str, *job: Any) -> None:
    """Compile `program` ("sensitivities" or "input_noise") of `model` in the library's
    background thread once the current public call returns (`_compile_in_background`);
    its state under ``("background", program)`` in the model's entry."""
    entry = _entry(model)
    if ("background", program) in entry:
        return
    entry[("background", program)] = "queued"
    _threads.after_call(lambda: _compile_in_background(model, program, *job))


def _compile_in_background(
    model: Model,
    program: str,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    pvec: FloatArray,
    names: tuple[str, ...],
    x0_free: tuple[int, ...],
    substeps: int,
    interpolation: Interpolation = "linear",
    extra: tuple[FloatArray, ...] = (),
) -> None:
    """The background job: `program` traced, compiled (by XLA, or read from the disk
    cache) and run once with the arguments of the call that queued it, which fills
    JAX's cache for the shapes of the model's next call. Sets the state to "ready",
    or "failed" (the numpy path then stays, silently: logged at debug level)."""
    entry = _entry(model)
    key = ("background", program)
    entry[key] = "compiling"
    preload_jax()
    try:
        if not available(model, time, x0, controls, pvec):
            entry[key] = "failed"
            return
        args = _sensitivity_args(
            model, time, controls, x0, pvec, names, x0_free, substeps, interpolation
        )
        with quiet_warnings():
            got = _compiled(model, "sensitivities")(*args)
            if program == "input_noise":
                inverse_variances, sigma = extra
                J = np.asarray(got[1], dtype=np.float64)
                weighted = np.zeros((*J.shape[:2], -(-J.shape[2] // 8) * 8))
                weighted[:, :, : J.shape[2]] = J * inverse_variances[None, :, None]
                fn = _compiled(model, "input_noise")
                got = (fn(*got[2:5], time, *args[7:9], pvec, args[9], weighted, sigma),)
            np.asarray(got[0])  # waits for the run
    except Exception:
        _log.debug("aeroid: compiling %s of model %r failed", program, model.name, exc_info=True)
        entry[key] = "failed"
        return
    entry[key] = "ready"


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
    entry = _entry(model)
    pvec = _pmatrix(model, params, 1)[0]
    x0 = np.asarray(x0, dtype=np.float64)
    state = entry.get(("background", "input_noise"))
    if not entry.get("sensitivities_compiled") or (_background() and state != "ready"):
        # a model whose fit ran in numpy, or whose program for this is not compiled yet:
        # the same adjoint in numpy, no compilation in the foreground
        from . import shooting as _shooting

        got = _shooting.input_noise_scatter(
            model, time, controls, x0, params, names, x0_free, substeps, inverse_variances, sigma
        )
        if got is not None:
            queued = entry.get(("background", "sensitivities")) is not None
            if _background() and state is None and (queued or entry.get("sensitivities_compiled")):
                # compiled in the background too (after the sensitivities, where queued)
                extra = (np.asarray(inverse_variances, dtype=np.float64), np.asarray(sigma))
                job = (time, controls, x0, pvec, tuple(names), tuple(x0_free), substeps)
                _queue(model, "input_noise", *job, "linear", extra)
            return got
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
    with quiet_warnings():
        e = control_excess(time, u)  # straight lines: the scatter's rule (`_jax_rk4`)
        scatter = fn(xs, phi, hx, time, u, e, pvec, np.int32(substeps), weighted, s)
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
    interpolation: Interpolation = "linear",
) -> tuple[FloatArray, ...]:
    args = _sensitivity_args(
        model, time, controls, x0, pvec, names, x0_free, substeps, interpolation
    )
    u = args[7]
    key = (pvec.tobytes(), x0.tobytes(), tuple(names), tuple(x0_free), int(substeps), interpolation)
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
    with quiet_warnings():
        got = fn(*args)
    out = tuple(np.asarray(a, dtype=np.float64) for a in got)
    for a in out:  # shared with the next caller at the same point: nobody writes to them
        a.flags.writeable = False
    keep = out[1].nbytes <= _KEEP_BYTES
    _LAST_SENSITIVITIES[:] = [weakref.ref(model), key, time, u, out] if keep else []
    return out


def _sensitivity_args(
    model: Model,
    time: FloatArray,
    controls: FloatArray,
    x0: FloatArray,
    pvec: FloatArray,
    names: Sequence[str],
    x0_free: Sequence[int],
    substeps: int,
    interpolation: Interpolation = "linear",
) -> tuple[Any, ...]:
    """The arguments of the compiled sensitivities program (`_jax_rk4._tangent_linear`)."""
    pidx = np.array([model.parameter_names.index(n) for n in names], dtype=np.int64)
    xidx = np.asarray(list(x0_free), dtype=np.int64)
    theta = np.concatenate([pvec[pidx], x0[xidx]])
    u = np.asarray(controls, dtype=np.float64)
    dynamic = _dynamic_parameters(model, time, x0, u)
    dpos = np.flatnonzero(np.isin(pidx, dynamic)).astype(np.int64)
    e = control_excess(time, u, interpolation)
    return theta, pvec, pidx, dpos, x0, xidx, time, u, e, np.int32(substeps)


def _last_states(
    model: Model,
    time: FloatArray,
    x0: FloatArray,
    u: FloatArray,
    pvec: FloatArray,
    substeps: int,
    interpolation: Interpolation = "linear",
) -> FloatArray | None:
    """The states (n_t, n_x) of the last sensitivity pass when it was at this point:
    the same initial state, controls, interpolation and substeps, and the same values of the
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
        or key[5] != interpolation
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
    interpolation: Interpolation = "linear",
) -> Callable[..., Any] | None:
    """Compiled RK4 propagation over one sample interval, for the nonlinear filters.

    Returns ``propagate(k, X, P, jacobian=False)`` moving points ``X`` (M, n_x)
    with parameter rows ``P`` (M, n_p) (model parameter order) from sample k
    to k+1 of `time` with `controls` (n_t, n_u), exactly as
    `_integrate.rk4` would with `substeps` and `interpolation`; with ``jacobian=True`` it returns
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
    e = control_excess(t, u, interpolation)

    def propagate(k: int, X: FloatArray, P: FloatArray, jacobian: bool = False) -> Any:
        args = (X, t[k], t[k + 1], u[k], u[k + 1], e[k], P, m)
        with quiet_warnings():
            nxt = np.asarray(pts(*args), dtype=np.float64)
            if not jacobian:
                return nxt
            return nxt, np.asarray(lin(*args), dtype=np.float64)

    return propagate
