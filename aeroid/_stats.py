"""Distribution functions in closed form, so that no call imports `scipy.stats`.

`scipy.stats` costs about a second to import and `scipy.special` a tenth of
one; the Ljung–Box p-value and the normal quantiles the library needs have
closed forms that the standard library evaluates to full double precision.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Mapping, Sequence
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray

_STANDARD_NORMAL = NormalDist()


def spread_over_noise(y: NDArray[np.float64]) -> float:
    """RMS of `y` about its mean over its noise RMS, the noise estimated from first
    differences: white noise of variance s^2 gives differences of variance 2 s^2, a
    response slow against the sample rate next to none."""
    noise = float(np.std(np.diff(y))) / math.sqrt(2.0)
    spread = float(np.std(y))
    return spread / noise if noise > 0 else (math.inf if spread > 0 else 0.0)


def chi2_sf(q: float, dof: int) -> float:
    """Upper tail P(X > q) of the chi-square distribution with integer `dof` (NaN below 1).

    The regularised upper incomplete gamma function Q(k/2, q/2) in its finite
    series for integer k (Abramowitz & Stegun 26.4.4-26.4.5): with x = q/2,
    even k = 2m gives ``e^-x sum_{i<m} x^i / i!`` and odd k = 2m + 1 gives
    ``erfc(sqrt x) + e^-x sum_{i<m} x^(i+1/2) / Gamma(i + 3/2)``. Each term is
    formed in logarithms, so a large `q` or `dof` neither overflows nor
    underflows before the sum.
    """
    k = operator.index(dof)  # numpy integers too; a float `dof` is a caller's bug
    if k < 1 or math.isnan(q):
        return math.nan  # as scipy.stats.chi2.sf: no distribution without a degree of freedom
    if q <= 0.0:
        return 1.0
    if math.isinf(q):
        return 0.0
    x = 0.5 * q
    log_x = math.log(x)
    m, odd = divmod(k, 2)
    if odd:
        terms = [math.exp((i + 0.5) * log_x - x - math.lgamma(i + 1.5)) for i in range(m)]
        return min(1.0, math.erfc(math.sqrt(x)) + math.fsum(terms))
    terms = [math.exp(i * log_x - x - math.lgamma(i + 1.0)) for i in range(m)]
    return min(1.0, math.fsum(terms))


def norm_ppf(p: float) -> float:
    """Quantile of the standard normal distribution at probability `p` in (0, 1)."""
    return _STANDARD_NORMAL.inv_cdf(p)


def wald_p_value(b: NDArray[np.float64], covariances: Sequence[NDArray[np.float64]]) -> float:
    """P-value of the Wald test that the estimates `b` are jointly zero.

    The first of `covariances` that is positive definite is used: a sandwich
    estimate need not be (its pair terms off the ``k/T`` grid can leave it
    indefinite, and a negative quadratic form would read as no evidence at
    all), so a caller lists it before the model-based one. Zero when none
    is: no test can then say the estimates may be dropped.
    """
    b = np.asarray(b, dtype=np.float64)
    for cov in covariances:
        c = np.asarray(cov, dtype=np.float64)
        try:
            lower = np.linalg.cholesky(0.5 * (c + c.T))
        except np.linalg.LinAlgError:
            continue
        z = np.linalg.solve(lower, b)
        q = float(z @ z)
        return chi2_sf(q, b.size) if math.isfinite(q) else 0.0
    return 0.0


def t_quantile(nu: NDArray[np.float64], level: float = 0.95) -> NDArray[np.float64]:
    """The two-sided `level` quantile of Student's t with `nu` degrees of freedom
    (floored at one; the normal's where `nu` is infinite)."""
    from scipy.special import ndtri, stdtrit

    q = 0.5 + 0.5 * float(level)
    nu = np.asarray(nu, dtype=np.float64)
    finite = np.isfinite(nu)
    t = stdtrit(np.maximum(np.where(finite, nu, 1.0), 1.0), q)
    return np.asarray(np.where(finite, t, ndtri(q)), dtype=np.float64)


def margins(
    stderr: Mapping[str, float], dof: Mapping[str, float], level: float
) -> dict[str, float]:
    """Half-widths of two-sided `level` intervals: each standard error times the t
    quantile of its degrees of freedom (the normal's where none is given)."""
    from ._checks import as_float

    value = as_float(level)  # a parameter's name is no level
    if value is None or not 0.0 < value < 1.0:
        from .errors import IdentificationError

        raise IdentificationError(f"level must lie strictly between 0 and 1, got {level!r}")
    level = value
    names = list(stderr)
    q = t_quantile(np.array([dof.get(n, np.inf) for n in names], dtype=float), level)
    return {n: float(q[i] * stderr[n]) for i, n in enumerate(names)}
