"""A frequency response as a function of ω for the handling-qualities metrics
(`aeroid.frequency.handling_qualities`): measured points, or an analytic transfer function
whose crossings are refined on the continuous curve.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AeroidError, IdentificationError
from ..io.data import as_float, plain
from ._response_records import CompositeResponse, ResponseChannel, _unwrapped_phase
from ._transfer import transfer_response
from .frequency_id import _resolve_response

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_DENSE = np.geomspace(1e-3, 1e3, 6001)


class _Response:
    """Frequency response as a function of ω: analytic (refinable) or tabulated."""

    def __init__(
        self,
        response_or_tf: Any,
        input: str | None,
        output: str | None,
        name: str = "response_or_tf",
    ) -> None:
        self.analytic: Callable[[FloatArray], ComplexArray] | None = None
        if isinstance(response_or_tf, (CompositeResponse, ResponseChannel)):
            ch = _resolve_response(response_or_tf, input, output, name)
            self.omega = ch.frequency
            self.values = ch.response
        else:
            self.analytic = _as_function(response_or_tf, name)
            self.omega = _DENSE
            self.values = self.analytic(_DENSE)
        if self.omega.size < 2:
            raise IdentificationError(f"{name}: need at least two frequencies")
        if not np.any(np.abs(self.values) > 0):
            raise IdentificationError(
                f"{name}: the response is zero at every frequency, so it has no "
                "phase or gain to cross"
            )

    def scaled(self, factor: Callable[[FloatArray], ComplexArray]) -> _Response:
        out = object.__new__(_Response)
        base = self.analytic
        out.analytic = None if base is None else (lambda w: base(w) * factor(w))
        out.omega = self.omega
        out.values = self.values * factor(self.omega)
        return out

    def phase(self) -> FloatArray:
        return _unwrapped_phase(self.values)

    def crossing(self, level: FloatArray, target: float) -> float:
        """First ω where `level` (on self.omega) falls through `target`; NaN if never."""
        below = np.flatnonzero((level[:-1] > target) & (level[1:] <= target))
        if below.size == 0:
            return float("nan")
        return self._refined(level, int(below[0]), target)

    def _refined(self, level: FloatArray, i: int, target: float) -> float:
        """ω where `level` meets `target` between grid points i and i + 1: interpolated in
        log ω, then refined on the continuous curve of an analytic response."""
        w0, w1 = float(self.omega[i]), float(self.omega[i + 1])
        y0, y1 = float(level[i]) - target, float(level[i + 1]) - target
        guess = float(np.exp(np.log(w0) + (np.log(w1) - np.log(w0)) * y0 / (y0 - y1)))
        if self.analytic is None:
            return guess
        # refine on the continuous phase/gain: the branch is fixed by the tabulated value
        ref = float(level[i])
        kind = self._kind

        def f(w: float) -> float:
            h = self.analytic(np.array([w]))[0]  # type: ignore[misc]
            if kind == "phase":
                v = np.degrees(np.angle(h))
                v += 360.0 * np.round((ref - v) / 360.0)
            else:
                v = 20.0 * np.log10(abs(h))
            return float(v - target)

        import scipy.optimize  # only an analytic response is refined

        try:
            return float(scipy.optimize.brentq(f, w0, w1, xtol=1e-14, rtol=1e-12))
        except ValueError:
            return guess

    def phase_crossings(self, target: float) -> FloatArray:
        """Every ω where the phase crosses `target` + k·360° (any k), rising or falling,
        ascending; a grid point on the line counts once."""
        self._kind = "phase"
        ph = self.phase()
        turn = np.floor((ph - target) / 360.0)  # which band of 360° each point lies in
        found: list[float] = []
        for i in np.flatnonzero(np.diff(turn) != 0):
            lo, hi = sorted((int(turn[i]), int(turn[i + 1])))
            # a coarse grid may step over several lines at once
            found += [self._refined(ph, int(i), target + 360.0 * k) for k in range(lo + 1, hi + 1)]
        return np.unique(np.asarray(found, dtype=np.float64))

    def at_zero(self) -> complex:
        """L(0) of an analytic response (NaN for a measured one or a pole at ω = 0)."""
        if self.analytic is None:
            return complex("nan")
        try:
            with np.errstate(all="ignore"):
                return complex(self.analytic(np.zeros(1))[0])
        except (AeroidError, ValueError, ZeroDivisionError):
            return complex("nan")  # a fit that cannot be read at ω = 0 has no DC crossover

    _kind = "phase"

    def phase_crossing(self, target: float) -> float:
        self._kind = "phase"
        return self.crossing(self.phase(), target)

    def gain_crossing(self, target_db: float) -> float:
        self._kind = "gain"
        with np.errstate(divide="ignore"):
            return self.crossing(20.0 * np.log10(np.abs(self.values)), target_db)

    def at(self, w: float) -> complex:
        if self.analytic is not None:
            return complex(self.analytic(np.array([w]))[0])
        if not self.omega[0] <= w <= self.omega[-1]:
            return complex("nan")
        lw = np.log(self.omega)
        mag = np.interp(np.log(w), lw, np.log(np.abs(self.values)))
        ph = np.interp(np.log(w), lw, np.radians(self.phase()))
        return complex(np.exp(mag + 1j * ph))

    def phase_at(self, w: float) -> float:
        """Unwrapped phase (deg) at w on the branch of the tabulated phase."""
        if not np.isfinite(w):
            return float("nan")
        ph = self.phase()
        if self.analytic is None:
            if not self.omega[0] <= w <= self.omega[-1]:
                return float("nan")
            return float(np.interp(np.log(w), np.log(self.omega), ph))
        v = float(np.degrees(np.angle(self.at(w))))
        ref = float(np.interp(np.log(w), np.log(self.omega), ph))
        return v + 360.0 * float(np.round((ref - v) / 360.0))


def _integrate(w: FloatArray) -> ComplexArray:
    return np.asarray(1.0 / (1j * np.asarray(w, dtype=np.float64)), dtype=np.complex128)


def _as_function(tf: Any, name: str = "response_or_tf") -> Callable[[FloatArray], ComplexArray]:
    if hasattr(tf, "evaluate") and callable(tf.evaluate):
        return lambda w: np.asarray(tf.evaluate(w), dtype=np.complex128)
    if isinstance(tf, tuple) and len(tf) in (2, 3):
        try:
            num = np.atleast_1d(np.asarray(tf[0], dtype=np.float64))
            den = np.atleast_1d(np.asarray(tf[1], dtype=np.float64))
        except (TypeError, ValueError):
            num = den = np.zeros((0, 0))  # reported as not 1-D below
        # NaN coefficients would surface as a phase that never crosses, or NaN margins
        for what, arr, given in (("numerator", num, tf[0]), ("denominator", den, tf[1])):
            if arr.ndim != 1 or not arr.size or not np.all(np.isfinite(arr)):
                raise IdentificationError(
                    f"{name}: the {what} must be a 1-D sequence of finite "
                    f"coefficients (highest power first), got {plain(given)}"
                )
        if not np.any(den != 0):
            raise IdentificationError(
                f"{name}: the denominator is zero (all coefficients), got {plain(tf[1])}"
            )
        tau = _delay(tf[2], name) if len(tf) == 3 else 0.0

        def h(w: FloatArray) -> ComplexArray:
            with np.errstate(all="ignore"):
                return transfer_response(num, den, w, delay=tau)

        return h
    raise IdentificationError(
        f"{name}: expected a CompositeResponse, ResponseChannel, a fit with "
        "evaluate(ω), or (numerator, denominator[, delay]) coefficient arrays (highest power "
        f"first), got {type(tf).__name__}"
    )


def _delay(value: Any, name: str) -> float:
    """The delay of a ``(num, den, delay)`` tuple in seconds: a finite number."""
    tau = as_float(value)  # text and bools are no delay (float() would read True as 1 s)
    if tau is None or not np.isfinite(tau):
        raise IdentificationError(
            f"{name}: the delay (third entry) must be a finite number of seconds, "
            f"got {plain(value)}"
        )
    return tau
