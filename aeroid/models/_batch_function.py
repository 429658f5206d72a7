"""`BatchFunction`: a user's model function called on a whole batch of points.

A function written for one point is tried once on a batch; one that broadcasts
(and agrees with the single-point calls) is called batched from then on, any
other one point at a time.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._threads import in_background, user_stacklevel
from ..errors import AeroidError, ModelDefinitionError, SimulationError

FloatArray = NDArray[np.float64]
UserFunction = Callable[[Any, Any, Any, Mapping[str, Any]], Any]
# A function's values and Jacobians in closed form at points with a time each:
# (t (N,), x (n_x, N), u (n_u, N), p name -> float, names) -> (values (n_out, N),
# d/dx (N, n_out, n_x), d/d names (N, n_out, len(names)), d/du (N, n_out, n_u)), or None
# where it does not cover the point (central differences are taken instead).
ClosedForm = Callable[
    [FloatArray, FloatArray, FloatArray, Mapping[str, float], tuple[str, ...]],
    tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None,
]
# Points per call of a broadcasting function evaluated at many points with a time each
# (`BatchFunction.at_times`), for calls of more than `_CHUNK_ABOVE` points: small enough
# that the temporaries of a model stay in cache, large enough (and the calls so large)
# that the interpreter's overhead of the extra calls stays small.
_CHUNK = 16384
_CHUNK_ABOVE = 4 * _CHUNK


def _same(a: FloatArray, b: FloatArray) -> bool:
    """a equals b to 1e-10 relative, NaN matching NaN (a cheap `np.allclose`)."""
    with np.errstate(invalid="ignore"):
        close = (a == b) | (np.abs(a - b) <= 1e-10 * np.abs(b)) | (np.isnan(a) & np.isnan(b))
    return bool(np.all(close))


class BatchFunction:
    """Evaluate a user function ``f(t, x, u, p)`` on a batch of points.

    The user's function is called once with arrays of shape (n, batch) when it
    broadcasts (checked once, against member-by-member calls), and in a loop
    otherwise. A call that raises, or returns the wrong number of values, is
    reported naming the function's `role`, the model and the time.
    """

    def __init__(
        self,
        fun: UserFunction,
        n_out: int,
        parameter_names: tuple[str, ...],
        *,
        role: str = "dynamics",
        model_name: str = "model",
    ) -> None:
        self.fun = fun
        self.n_out = n_out
        self.parameter_names = parameter_names
        self.role = role
        self.model_name = model_name
        self.broadcasts: bool | None = None
        # False once a call with one time per point (an array t) has failed or
        # disagreed with calls at one time each
        self.time_broadcasts: bool | None = None
        # (n, times) of recent agreements: RK4's stage times take turns (a few keys)
        self._times_checked: set[tuple[float, ...]] = set()
        # time grids on which `lti_form` has checked every member at every sample
        self.lti_grids: dict[tuple[int, int], None] = {}
        # the function's Jacobians in closed form, where its author supplies them: the
        # linearised RK4 of Newton's method over the record (`shooting`) then takes
        # them instead of central differences over extra columns
        self.jacobian: ClosedForm | None = None
        # True once a call on numpy values returned a JAX array: a function written in
        # jax.numpy, which numpy's loops would run op by op through JAX's dispatcher
        # (each `jax.lax.cond` a compilation of its own), so compiling it always pays
        self.jax_written = False
        # such a function jit-compiled by JAX (per shape of its arguments): numpy's paths
        # call it without the dispatcher's cost per operation; False where it does not
        # trace (a Python `if` on a state), which then runs as written
        self._jitted: Any = None

    def _where(self) -> str:
        return f"the {self.role} of model {self.model_name!r}"

    def _evaluate(self, t: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        """The user's function, through its JAX compilation where it is written in JAX."""
        if self.jax_written and self._jitted is not False:
            try:
                if self._jitted is None:
                    import jax

                    self._jitted = jax.jit(self.fun)
                with np.errstate(all="ignore"):
                    return self._jitted(t, x, u, dict(p))
            except Exception:
                # as written: where that fails too the arguments were at fault (a batch
                # the function does not broadcast over), else it does not trace
                out = self.fun(t, x, u, p)
                self._jitted = False
                return out
        return self.fun(t, x, u, p)

    def _real(self, raw: Any, t: Any) -> FloatArray:
        """The function's values as float64; complex values are refused (a cast would
        drop their imaginary part in silence)."""
        out = np.asarray(raw)
        if out.dtype.kind == "c":
            at = float(np.ravel(t)[0])
            raise ModelDefinitionError(
                f"{self._where()} returned complex values at t = {at:.6g} s; a model's "
                "states and outputs are real"
            )
        return np.asarray(out, dtype=np.float64)

    def _single(self, t: float, x: FloatArray, u: FloatArray, p: Mapping[str, float]) -> FloatArray:
        try:
            raw = self._evaluate(t, x, u, p)
            if not self.jax_written and type(raw).__module__.startswith(("jax", "jaxlib")):
                self.jax_written = True
            out = self._real(raw, t)
        except AeroidError:
            raise
        except Exception as exc:
            raise SimulationError(
                f"{self._where()} raised {type(exc).__name__} at t = {t:.6g} s: {exc}"
            ) from exc
        if out.size != self.n_out:
            raise ModelDefinitionError(
                f"{self._where()} returned {out.size} values (shape {out.shape}) at "
                f"t = {t:.6g} s; expected {self.n_out}"
            )
        return out.reshape(self.n_out)

    def _loop(
        self, t: Any, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        batch = x.shape[1]
        tt = np.broadcast_to(np.asarray(t, dtype=np.float64), (batch,))
        out = np.empty((self.n_out, batch))
        for b in range(batch):
            pb = {k: float(v[b]) for k, v in p.items()}
            out[:, b] = self._single(float(tt[b]), x[:, b], u[:, b], pb)
        return out

    def detect(self, t: float, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]) -> None:
        """Decide once whether the function broadcasts over a batch axis."""
        batch = x.shape[1]
        if batch < 2:
            return
        reference = self._loop(t, x, u, p)
        why = "returned other values on arrays than point by point"
        try:
            with np.errstate(all="ignore"):
                trial = self._real(self._evaluate(t, x, u, p), t)
            ok = trial.shape == (self.n_out, batch) and np.allclose(
                trial, reference, rtol=1e-10, atol=1e-300, equal_nan=True
            )
        except Exception as exc:  # any failure means "does not broadcast"
            ok = False
            why = f"raised {type(exc).__name__} on arrays ({exc})"
        self.broadcasts = bool(ok)
        if not ok and not self.jax_written and not in_background():
            # correct either way, but a loop in Python over every point and every
            # evaluation: say so once, with the usual cause
            warnings.warn(
                f"{self._where()} {why}, so it is evaluated one point at a time, many "
                "times slower: write it for arrays of points (np.where, not a Python "
                "`if` on a state or input; np.sin, not math.sin)",
                UserWarning,
                stacklevel=user_stacklevel(),
            )

    def __call__(
        self, t: Any, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        if self.broadcasts is None:
            self.detect(float(np.ravel(t)[0]), x, u, p)
        if self.broadcasts:
            try:
                out = self._real(self._evaluate(t, x, u, p), t)
                if out.shape == (self.n_out, x.shape[1]):
                    return out
            except Exception:  # evaluated point by point below, which names the culprit
                pass
            if np.ndim(t) == 0:
                # broadcast at the first time but not at this one: a branch on t
                self.broadcasts = False
        return self._loop(t, x, u, p)

    def _chunked(
        self, t: FloatArray, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        """The function on points with a time each, called on runs of `_CHUNK` points:
        a model's temporaries then stay in the processor's cache (a model of a hundred
        operations runs two to three times faster on ten thousand points at a time than
        on a hundred thousand). Points are independent: the values are the same."""
        n = t.size
        if n <= _CHUNK_ABOVE:
            return self._real(self._evaluate(t, x, u, p), t)
        parts = []
        for lo in range(0, n, _CHUNK):
            s = slice(lo, min(n, lo + _CHUNK))
            part = self._real(
                self._evaluate(t[s], x[:, s], u[:, s], {a: v[s] for a, v in p.items()}), t
            )
            if part.shape != (self.n_out, s.stop - s.start):
                return part  # the caller reports the shape
            parts.append(part)
        return np.concatenate(parts, axis=1)

    def at_times(
        self, t: FloatArray, x: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
    ) -> FloatArray:
        """Evaluate at points with a time each: t (N,), x (n_x, N), u (n_u, N), p name -> (N,).

        One call with an array ``t`` when that gives what calls at one time each
        give, else one call per distinct time, or a loop over the points for a
        function that does not broadcast at all. The array call is checked
        against calls at four of its times (the last among them) whenever those
        times change: a function that reads one element of an array ``t`` would
        otherwise hide a change in time.
        """
        n = t.size
        if self.broadcasts is None and n >= 2:
            k = min(n, 8)
            self.detect(float(t[0]), x[:, :k], u[:, :k], {a: v[:k] for a, v in p.items()})
        if not self.broadcasts:
            return self._loop(t, x, u, p)
        if self.time_broadcasts is not False:
            try:
                with np.errstate(all="ignore"):
                    out = self._chunked(t, x, u, p)
                good = out.shape == (self.n_out, n)
            except Exception:  # an array t it cannot take: one time per call below
                good = False
            key = (n, *(float(t[i]) for i in (n - 1, n // 2, n // 4, (3 * n) // 4)))
            if good and key not in self._times_checked:
                for tk in sorted(set(key[1:])):
                    sel = np.flatnonzero(t == tk)
                    ref = self(tk, x[:, sel], u[:, sel], {a: v[sel] for a, v in p.items()})
                    if not _same(out[:, sel], ref):
                        good = False
                        break
                if good:
                    if len(self._times_checked) >= 16:
                        self._times_checked.clear()
                    self._times_checked.add(key)
            if good:
                return out
            self.time_broadcasts = False
        times, inverse = np.unique(t, return_inverse=True)
        out = np.empty((self.n_out, n))
        for j, tk in enumerate(times.tolist()):
            sel = np.flatnonzero(inverse == j)
            out[:, sel] = self(tk, x[:, sel], u[:, sel], {a: v[sel] for a, v in p.items()})
        return out
