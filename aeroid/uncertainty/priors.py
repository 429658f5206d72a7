"""Prior distributions for Bayesian inference: `Normal`, `Uniform`, `LogUniform`, `HalfNormal`.

Every prior is a small frozen object with a vectorised, normalised
``log_pdf``, a seeded ``sample``, its ``support`` and a typical ``center`` and
``scale`` (used to place walkers when no better start is given).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._value_checks import real_array
from ..errors import InferenceError
from ..io.data import as_float

__all__ = ["HalfNormal", "InvalidPriorError", "LogUniform", "Normal", "Prior", "Uniform"]

FloatArray = NDArray[np.float64]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


class InvalidPriorError(InferenceError, ValueError):
    """A prior was constructed with invalid arguments (also a `ValueError`)."""


def _number(cls: str, name: str, value: Any) -> float:
    v = as_float(value)
    if v is None:
        raise InvalidPriorError(f"{cls}: {name} must be a number, got {value!r}")
    if not math.isfinite(v):
        raise InvalidPriorError(f"{cls}: {name} must be finite, got {value!r}")
    return v


def _positive(cls: str, name: str, value: Any) -> float:
    v = _number(cls, name, value)
    if v <= 0.0:
        raise InvalidPriorError(f"{cls}: {name} must be > 0, got {value!r}")
    return v


def _ordered(cls: str, lo: Any, hi: Any) -> tuple[float, float]:
    a = _number(cls, "lo", lo)
    b = _number(cls, "hi", hi)
    if not a < b:
        raise InvalidPriorError(f"{cls}: lo must be < hi, got lo={lo!r}, hi={hi!r}")
    return a, b


def _values(prior: Any, x: ArrayLike) -> FloatArray:
    """`x` as float64, or an `InvalidPriorError` naming the prior."""
    return real_array(x, f"{type(prior).__name__}.log_pdf: x", InvalidPriorError)


def _size(prior: Any, size: Any) -> Any:
    """`size` as numpy's generators take it, or an `InvalidPriorError` naming it."""
    if size is None:
        return None
    dims = (size,) if not isinstance(size, tuple) else size
    if not all(
        isinstance(d, (int, np.integer)) and not isinstance(d, bool) and d >= 0 for d in dims
    ):
        raise InvalidPriorError(
            f"{type(prior).__name__}.sample: size must be a count or a tuple of counts "
            f"(>= 0), got {size!r}"
        )
    return size


def _out(values: FloatArray, x: ArrayLike) -> Any:
    """A float for scalar input, an array otherwise."""
    return float(values) if np.ndim(x) == 0 else values


class Prior(ABC):
    """Base class of prior distributions over one scalar parameter.

    Subclasses are frozen dataclasses that implement `log_pdf`, `sample`,
    `support`, `center` and `scale`. Any object deriving from `Prior` can be
    passed to `aeroid.infer`.
    """

    @abstractmethod
    def log_pdf(self, x: ArrayLike) -> Any:
        """Normalised log-density at `x` (element-wise); ``-inf`` outside the support.

        Returns a float for scalar input and an array of ``x``'s shape otherwise.
        """

    @abstractmethod
    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        """Draw independent values with the generator `rng`."""

    @property
    @abstractmethod
    def support(self) -> tuple[float, float]:
        """Closed interval ``(lo, hi)`` holding all the probability (may be infinite)."""

    @property
    @abstractmethod
    def center(self) -> float:
        """The median: a typical value, used as a default starting point."""

    @property
    @abstractmethod
    def scale(self) -> float:
        """The standard deviation: a typical spread, used to size starting balls."""

    def _mask(self, x: FloatArray) -> NDArray[np.bool_]:
        lo, hi = self.support
        with np.errstate(invalid="ignore"):
            return (x >= lo) & (x <= hi)


@dataclass(frozen=True)
class Normal(Prior):
    """Gaussian prior ``N(mu, sigma²)``.

    Parameters
    ----------
    mu : float
        Mean.
    sigma : float
        Standard deviation, > 0.
    """

    mu: float
    sigma: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "mu", _number("Normal", "mu", self.mu))
        object.__setattr__(self, "sigma", _positive("Normal", "sigma", self.sigma))

    def log_pdf(self, x: ArrayLike) -> Any:
        z = (_values(self, x) - self.mu) / self.sigma
        return _out(-0.5 * z * z - math.log(self.sigma) - _LOG_SQRT_2PI, x)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return rng.normal(self.mu, self.sigma, _size(self, size))

    @property
    def support(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    @property
    def center(self) -> float:
        return self.mu

    @property
    def scale(self) -> float:
        return self.sigma


@dataclass(frozen=True)
class Uniform(Prior):
    """Flat prior on ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : float
        Finite bounds with ``lo < hi``.
    """

    lo: float
    hi: float

    def __post_init__(self) -> None:
        lo, hi = _ordered("Uniform", self.lo, self.hi)
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def log_pdf(self, x: ArrayLike) -> Any:
        xa = _values(self, x)
        out = np.where(self._mask(xa), -math.log(self.hi - self.lo), -np.inf)
        return _out(out, x)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return rng.uniform(self.lo, self.hi, _size(self, size))

    @property
    def support(self) -> tuple[float, float]:
        return (self.lo, self.hi)

    @property
    def center(self) -> float:
        return 0.5 * (self.lo + self.hi)

    @property
    def scale(self) -> float:
        return (self.hi - self.lo) / math.sqrt(12.0)


@dataclass(frozen=True)
class LogUniform(Prior):
    """Prior flat in ``log x`` on ``[lo, hi]`` (density ∝ 1/x), for positive scales.

    Parameters
    ----------
    lo, hi : float
        Finite bounds with ``0 < lo < hi``.
    """

    lo: float
    hi: float

    def __post_init__(self) -> None:
        lo, hi = _ordered("LogUniform", self.lo, self.hi)
        if lo <= 0.0:
            raise InvalidPriorError(f"LogUniform: lo must be > 0, got lo={self.lo!r}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def log_pdf(self, x: ArrayLike) -> Any:
        xa = _values(self, x)
        inside = self._mask(xa)
        with np.errstate(divide="ignore", invalid="ignore"):
            val = -np.log(np.where(inside, xa, 1.0)) - math.log(math.log(self.hi / self.lo))
        return _out(np.where(inside, val, -np.inf), x)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return np.exp(rng.uniform(math.log(self.lo), math.log(self.hi), _size(self, size)))

    @property
    def support(self) -> tuple[float, float]:
        return (self.lo, self.hi)

    @property
    def center(self) -> float:
        return math.sqrt(self.lo * self.hi)

    @property
    def scale(self) -> float:
        r = math.log(self.hi / self.lo)
        m1 = (self.hi - self.lo) / r
        m2 = (self.hi**2 - self.lo**2) / (2.0 * r)
        return math.sqrt(max(m2 - m1 * m1, 0.0))


@dataclass(frozen=True)
class HalfNormal(Prior):
    """Half-Gaussian prior on ``[0, inf)``: ``|N(0, sigma²)|``, for positive scales.

    Parameters
    ----------
    sigma : float
        Scale of the parent Gaussian, > 0.
    """

    sigma: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", _positive("HalfNormal", "sigma", self.sigma))

    def log_pdf(self, x: ArrayLike) -> Any:
        xa = _values(self, x)
        z = xa / self.sigma
        val = -0.5 * z * z - math.log(self.sigma) - _LOG_SQRT_2PI + math.log(2.0)
        return _out(np.where(self._mask(xa), val, -np.inf), x)

    def sample(self, rng: np.random.Generator, size: int | tuple[int, ...] | None = None) -> Any:
        return np.abs(rng.normal(0.0, self.sigma, _size(self, size)))

    @property
    def support(self) -> tuple[float, float]:
        return (0.0, math.inf)

    @property
    def center(self) -> float:
        # median of |N(0, 1)| is the 75th percentile of N(0, 1)
        return 0.6744897501960817 * self.sigma

    @property
    def scale(self) -> float:
        return self.sigma * math.sqrt(1.0 - 2.0 / math.pi)
