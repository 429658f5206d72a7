"""`BatchSimulator`: `Model.simulate_batch` on one record, its arguments checked once.

A sampler scores thousands of parameter batches on one flight record; each call of
`simulate_batch` would check the time grid, the controls and the initial state again
and rebuild every parameter's array. Here that is done once, and `outputs` goes from
the parameters to the outputs in one compiled call when the calls expected pay for
the compilation (`aeroid.models.compiled.rk4_outputs`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import check_time
from ..errors import SimulationError
from . import integration as _integrate
from ._simulation_checks import _MAX_NODE_VALUES, _real, check_integrator
from ._simulation_results import BatchSimulation

if TYPE_CHECKING:
    from .model import Model

__all__ = ["BatchSimulator"]

FloatArray = NDArray[np.float64]

_log = logging.getLogger("aeroid")


class BatchSimulator:
    """`Model.simulate_batch` on one time grid, controls and initial state, checked once.

    Each call takes a batch of parameter values (a mapping of name to scalar or
    (batch,) array) and returns what `simulate_batch` returns for them, bit for
    bit: a sampler's thousands of calls pay no argument checks. With
    ``repeated`` (the number of calls the caller expects), `outputs` compiles the
    model's RK4 from the first call when that many calls pay for a compilation,
    parameters to outputs in one compiled call (equal to `simulate_batch`'s to
    rounding).
    """

    def __init__(
        self,
        model: Model,
        time: ArrayLike,
        controls: Any,
        x0: Any,
        *,
        method: str = "auto",
        substeps: int | None = None,
        rtol: float = 1e-9,
        atol: float = 1e-12,
        repeated: int = 0,
        control_interpolation: str | Mapping[str, str] = "linear",
    ) -> None:
        self.model = model
        self.time = check_time(time)
        check_integrator(method, substeps, rtol, atol)
        self.method, self.substeps, self.rtol, self.atol = method, substeps, rtol, atol
        self.interpolation = _integrate.check_control_interpolation(
            control_interpolation, controls=model.controls
        )
        self.u = model.control_array(self.time, controls)
        self.x0 = x0
        x0_arr = None if x0 is None or isinstance(x0, Mapping) else np.atleast_2d(_real(x0, "x0"))
        self._x0_batch = 1 if x0_arr is None else x0_arr.shape[0]
        self.repeated = int(repeated)
        # shown linear time-invariant (integrated exactly, in numpy) or not compiled: the
        # plain call from then on
        self._plain = False
        # the largest batch yet: smaller ones are padded to it (one compiled program)
        self._widest = 0
        # per batch size: initial states, controls and the nominal parameter rows
        self._batches: dict[int, tuple[FloatArray, FloatArray, FloatArray]] = {}
        # per (parameter names, output index, batch size): the padded rows of the compiled program's
        # last batch, only the given parameters' columns to fill in again (`_Lane`)
        self._lanes: dict[tuple[Any, ...], _Lane] = {}

    @cached_property
    def excess(self) -> FloatArray:
        """The controls' `control_excess` (straight or cubic between samples): the same for
        every batch, so computed once and not at every compiled call."""
        return _integrate.control_excess(self.time, self.u[0], self.interpolation)

    def _batch(self, parameters: Mapping[str, ArrayLike]) -> int:
        model = self.model
        unknown = sorted(set(parameters) - set(model.parameters))
        if unknown:
            raise SimulationError(
                f"parameters {unknown} are not parameters of model {model.name!r}"
            )
        sizes = {np.size(v) for v in parameters.values() if np.ndim(v) > 0}
        sizes |= {self.u.shape[0]} if self.u.shape[0] > 1 else set()
        sizes |= {self._x0_batch} if self._x0_batch > 1 else set()
        if len(sizes) > 1:
            raise SimulationError(
                f"batch sizes disagree between parameters, controls and x0: {sorted(sizes)}"
            )
        return sizes.pop() if sizes else 1

    def _arrays(
        self, parameters: Mapping[str, ArrayLike], batch: int
    ) -> tuple[FloatArray, FloatArray, dict[str, FloatArray]]:
        """Initial states (batch, n_x), controls (batch, n_t, n_u) and every parameter's
        values (batch,): fresh arrays of the parameters, shared ones of the rest."""
        model = self.model
        known = self._batches.get(batch)
        if known is None:
            X0 = model.initial_state(self.x0, batch)
            U = np.broadcast_to(self.u, (batch, self.time.size, model.n_controls))
            nominal = np.empty((len(model.parameters), batch))
            for i, v in enumerate(model.parameters.values()):
                nominal[i] = np.asarray(v, dtype=np.float64)
            for arr in (X0, nominal):
                arr.flags.writeable = False
            known = self._batches[batch] = (X0, U, nominal)
        X0, U, nominal = known
        # rows of a fresh copy: a model that writes into its parameters changes no other call
        p = dict(zip(model.parameters, nominal.copy(), strict=True))
        for k, given in parameters.items():
            p[k] = np.broadcast_to(np.asarray(given, dtype=np.float64), (batch,)).copy()
        return X0, U, p

    def __call__(self, parameters: Mapping[str, ArrayLike]) -> BatchSimulation:
        """`Model.simulate_batch` of these parameter values."""
        model, t = self.model, self.time
        batch = self._batch(parameters)
        X0, U, p = self._arrays(parameters, batch)
        if self.substeps is not None and self.method in ("auto", "rk4", "rk4_hold"):
            nodes = (t.size - 1) * (2 * int(self.substeps) + 1) * max(model.n_controls, 1) * batch
            if nodes > _MAX_NODE_VALUES:
                raise SimulationError(
                    f"substeps={int(self.substeps)}: RK4 would hold {nodes} control values "
                    f"({t.size} samples, batch {batch}); use fewer substeps or a finer time grid"
                )
        from . import compiled  # the same RK4, compiled once it pays

        # a single member (a sampler's starting point) as before: the compiled rollout of
        # a batch compiles once the calls expected pay for it
        now = batch > 1 and self._compile_now()
        hook = compiled.compiled_rollout if now else compiled.rk4_hook
        traj = _integrate.integrate(
            model,
            t,
            X0,
            U,
            p,
            method=self.method,
            substeps=self.substeps,
            rtol=self.rtol,
            atol=self.atol,
            compiled_rk4=hook,
            control_interpolation=self.interpolation,
        )
        outputs = model._outputs(t, traj.states, U, p)
        ok = traj.ok & np.all(np.isfinite(outputs), axis=(1, 2))
        fail_time = np.array(traj.fail_time, dtype=np.float64)
        failure = [""] * batch
        for b in np.flatnonzero(~ok).tolist():
            fail_time[b], failure[b] = model._failure(
                t, traj.states[b], outputs[b], float(traj.fail_time[b])
            )
        return BatchSimulation(t, traj.states, outputs, ok, fail_time, tuple(failure))

    def _compile_now(self) -> bool:
        """Whether the calls expected cost more numpy RK4 work than a compilation."""
        if self.repeated <= 1 or self.method not in ("auto", "rk4"):
            return False
        from .compiled import COMPILE_AFTER_CALLS

        work = self.repeated * 4 * (self.time.size - 1) * int(self.substeps or 1)
        return work > COMPILE_AFTER_CALLS

    def outputs(self, parameters: Mapping[str, ArrayLike], index: Any) -> FloatArray:
        """The outputs at `index` (batch, n_t, k), NaN throughout for a member that failed."""
        fast = self._compiled_outputs(parameters, index)
        if fast is not None:
            return fast
        res = self(parameters)
        y = res.outputs[:, :, index]
        y[~res.ok] = np.nan
        return np.asarray(y)

    def _compiled_outputs(
        self, parameters: Mapping[str, ArrayLike], index: Any
    ) -> FloatArray | None:
        model = self.model
        if self._plain or not self._compile_now() or self.u.shape[0] != 1 or self._x0_batch != 1:
            return None
        if not model.n_states:
            self._plain = True  # outputs algebraic in the controls: one numpy call, no RK4
            return None
        size = np.size(next(iter(parameters.values()))) if parameters else 1
        key = (tuple(parameters), tuple(int(i) for i in index), size)
        lane = self._lanes.get(key)
        if lane is not None:
            try:
                fast = lane.run(self, parameters)
            except Exception:  # the full path below decides (and logs) what went wrong
                del self._lanes[key]
                fast = None
            if fast is not None:
                return fast
        batch = self._batch(parameters)
        if batch < 2 and self._widest < 2:
            return None  # a single member before any batch (a sampler's start): as before
        self._widest = max(self._widest, batch)
        X0, U, p = self._arrays(parameters, batch)
        how = self.interpolation
        if _integrate.linear_path(model, self.time, X0, U, p, self.method, how) is not None:
            self._plain = True  # the exact solution, which the plain call takes from now on
            return None
        from .compiled import _pmatrix, padded_rows, rk4_outputs

        try:
            got = rk4_outputs(
                model,
                self.time,
                X0.T,
                self.u[0],
                p,
                self.substeps,
                index,
                pad=self._widest,
                interpolation=how,
            )
        except Exception as exc:  # a program JAX cannot build or run here: the plain path
            _log.debug("compiled outputs of model %r unavailable: %s", model.name, exc)
            got = None
        if got is None:
            self._plain = True
            return None
        # the integrator's exact path is ruled out for good (or not taken; never with
        # controls other than straight lines): the next batches of these names fill in
        # their columns of the same rows
        if not (self.method in ("auto", "exact") and model._maybe_lti and how == "linear"):
            rows = padded_rows(batch, self._widest)
            names = model.parameter_names
            columns = tuple(names.index(k) for k in parameters)
            P = _pmatrix(model, p, batch)[rows]
            X = np.ascontiguousarray(X0[rows])
            self._lanes[key] = _Lane(batch, rows.size, columns, X, P, key[1])
        y, ok = got
        y[~ok] = np.nan
        return y


class _Lane:
    """The rows of a compiled batch of one size and one set of parameter names: initial
    states and parameter rows padded as `rk4_outputs` pads them, into which a batch of
    the same names and size writes only its own columns (the same rows that
    `rk4_outputs` would build, bit for bit, without rebuilding the rest each call)."""

    def __init__(
        self,
        batch: int,
        padded: int,
        columns: tuple[int, ...],
        X: FloatArray,
        P: FloatArray,
        index: tuple[int, ...],
    ) -> None:
        self.batch, self.padded, self.columns, self.index = batch, padded, columns, index
        self.X, self.P = X, P
        for arr in (X, P):
            arr.flags.writeable = False

    def run(self, sim: BatchSimulator, parameters: Mapping[str, ArrayLike]) -> FloatArray | None:
        """The outputs of this batch, or None when it is not one of this lane's (another
        size, values that are not a float64 vector each, a wider batch seen since)."""
        batch = self.batch
        from .compiled import padded_rows

        if padded_rows(batch, sim._widest).size != self.padded:
            return None
        P = self.P.copy()
        for column, value in zip(self.columns, parameters.values(), strict=True):
            if not (
                isinstance(value, np.ndarray)
                and value.dtype == np.float64
                and value.shape == (batch,)
            ):
                return None
            P[:batch, column] = value
            P[batch:, column] = value[-1]
        from .compiled import rk4_output_rows

        y, ok = rk4_output_rows(
            sim.model,
            sim.time,
            sim.u[0],
            self.X,
            P,
            sim.substeps,
            self.index,
            batch,
            sim.excess,
        )
        y[~ok] = np.nan
        return y
