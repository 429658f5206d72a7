"""Checks of the aerodynamic database's inputs, each naming the flight, key or option
at fault, and the small statistics its fit and bands share."""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float
from .._stats import norm_ppf
from .._value_checks import finite_array, whole_number
from ..errors import DataFormatError, IdentificationError
from ._database_fit import Exponents, design

FloatArray = NDArray[np.float64]


def _number(value: Any, what: str) -> float:
    x = as_float(value)
    if x is None:
        raise DataFormatError(f"{what}: expected a number, got {value!r}")
    return x


def flight_values(
    name: str, condition: Any, estimates: Any, covariance: Any
) -> tuple[dict[str, float], dict[str, float], FloatArray]:
    """One flight's condition, estimates and covariance as numbers, or a `DataFormatError`:
    a condition or an estimate that is text, an infinite estimate (NaN marks a term the
    flight did not excite), a covariance that is not square over the estimates,
    symmetric, with non-negative variances and positive semi-definite."""
    for label, value in (("condition", condition), ("estimates", estimates)):
        if not isinstance(value, Mapping):
            raise DataFormatError(f"flight {name!r}: {label} must be a mapping, got {value!r}")
    cond = {str(k): _number(v, f"flight {name!r}: condition {k!r}") for k, v in condition.items()}
    est = {str(k): _number(v, f"flight {name!r}: estimate {k!r}") for k, v in estimates.items()}
    infinite = [k for k, v in est.items() if math.isinf(v)]
    if infinite:
        raise DataFormatError(
            f"flight {name!r}: estimate(s) {', '.join(infinite)} are infinite "
            "(NaN marks a term the flight did not excite)"
        )
    try:
        cov = np.array(covariance, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataFormatError(f"flight {name!r}: covariance is not numeric") from None
    n = len(est)
    if cov.shape != (n, n):
        raise DataFormatError(
            f"flight {name!r}: covariance is {cov.shape}, its {n} estimates need ({n}, {n})"
        )
    excited = np.array([math.isfinite(v) for v in est.values()], dtype=bool)
    block = cov[np.ix_(excited, excited)]
    if not np.all(np.isfinite(block)):
        return cond, est, cov  # a NaN variance marks a term as not excited, as before
    variances = np.diag(block)
    if np.any(variances < 0.0):
        bad = [k for k, e, v in zip(est, excited, np.diag(cov), strict=True) if e and v < 0.0]
        raise DataFormatError(f"flight {name!r}: negative variance of {', '.join(bad)}")
    scale = float(np.max(variances)) if variances.size else 0.0
    if not np.allclose(block, block.T, rtol=1e-9, atol=1e-12 * scale):
        raise DataFormatError(f"flight {name!r}: covariance is not symmetric")
    if block.size and np.min(np.linalg.eigvalsh(0.5 * (block + block.T))) < -1e-9 * scale:
        raise DataFormatError(f"flight {name!r}: covariance is not positive semi-definite")
    return cond, est, cov


def diagonal(name: str, estimates: Mapping[str, Any], stderr: Mapping[str, Any]) -> FloatArray:
    """The diagonal covariance of independent standard errors (NaN where none is given)."""
    if not isinstance(stderr, Mapping):
        raise DataFormatError(f"flight {name!r}: stderr must be a mapping, got {stderr!r}")
    unknown = sorted(str(k) for k in set(stderr) - set(estimates))
    if unknown:
        raise DataFormatError(
            f"flight {name!r}: standard errors given for {', '.join(unknown)}, which it "
            f"does not estimate (it estimates {', '.join(map(str, estimates)) or 'nothing'})"
        )
    se = {k: _number(v, f"flight {name!r}: stderr of {k!r}") for k, v in stderr.items()}
    negative = [k for k, v in se.items() if v < 0.0]
    if negative:
        raise DataFormatError(f"flight {name!r}: negative standard error of {', '.join(negative)}")
    exact = [k for k, v in se.items() if v == 0.0 and math.isfinite(_number(estimates[k], k))]
    if exact:
        raise DataFormatError(
            f"flight {name!r}: standard error 0 of {', '.join(exact)}: an estimate without "
            "uncertainty would outweigh every other flight; give its standard error (NaN "
            "for a term the flight did not excite)"
        )
    return np.diag([se[k] ** 2 if k in se else math.nan for k in estimates])


def database_options(
    flights: Any, kind: type, confidence: Any, max_degree: Any, f_in: Any
) -> tuple[list[Any], float, int, float]:
    """`aerodynamic_database`'s flights (each a `kind`) and options, checked."""
    if isinstance(flights, (str, bytes)) or not isinstance(flights, Sequence):
        raise DataFormatError(
            f"flights: expected a sequence of FlightCoefficients, got {type(flights).__name__}"
        )
    wrong = [i for i, f in enumerate(flights) if not isinstance(f, kind)]
    if wrong:
        raise DataFormatError(
            f"flights[{wrong[0]}]: expected FlightCoefficients, got "
            f"{type(flights[wrong[0]]).__name__}"
        )
    level = as_float(confidence)
    if level is None or not 0.0 < level < 1.0:
        raise IdentificationError(f"confidence must lie in (0, 1), got {confidence!r}")
    degree = whole_number(max_degree, "max_degree", IdentificationError, least=0)
    entry = as_float(f_in)
    if entry is None or not (math.isfinite(entry) and entry >= 0.0):
        raise IdentificationError(f"f_in must be a non-negative number, got {f_in!r}")
    return list(flights), level, degree, entry


def _few(names: Sequence[str], most: int = 8) -> str:
    """Names joined with commas, the first `most` of them and a count of the rest."""
    shown = ", ".join(names[:most])
    return shown + (f", ... {len(names) - most} more" if len(names) > most else "")


def key_list(keys: Sequence[str]) -> str:
    """A database's condition keys for a message or a summary."""
    return ", ".join(keys) or "none (each term a constant)"


def keys_and_terms(
    fit: Sequence[Any], keys: Sequence[str] | None, terms: Sequence[str] | None
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """`aerodynamic_database`'s keys and terms over the fitted flights (defaults: the
    keys every flight gives, every name a flight estimates).

    A key some flights lack leaves the default keys with a warning naming them (the
    database is then constant in it, which a misspelt key on one flight would do
    silently); no term to fit is an `IdentificationError`.
    """
    # one name is one key or term, not its letters
    keys = [keys] if isinstance(keys, str) else keys
    terms = [terms] if isinstance(terms, str) else terms
    if keys is None:
        given = list(dict.fromkeys(k for f in fit for k in f.condition))
        keys = [k for k in given if all(k in f.condition for f in fit)]
        for k in given:
            if k not in keys:
                lacking = [f.name for f in fit if k not in f.condition]
                warnings.warn(
                    f"condition key {k!r} is left out of the database: flight(s) "
                    f"{_few(lacking)} lack it (the default keys are those every flight "
                    f"gives); give it to every flight, or name the keys with keys=",
                    UserWarning,
                    stacklevel=3,
                )
    if terms is None:
        terms = list(dict.fromkeys(t for f in fit for t in f.estimates))
        if not terms:
            raise IdentificationError(
                "no flight estimates a coefficient (C<L,D,Y,l,m,n>_..., every flight's "
                "estimates are empty): there is nothing to fit; give the flights' "
                "coefficient estimates, and name the ones to fit with terms="
            )
    elif not terms:
        raise IdentificationError(f"terms must name at least one coefficient, got {terms!r}")
    return tuple(keys), tuple(str(t) for t in terms)


def condition_rows(
    term: str, keys: Sequence[str], condition: Mapping[str, ArrayLike] | ArrayLike
) -> FloatArray:
    """A condition (keys to arrays, or rows in the order of `keys`) as finite rows."""
    if isinstance(condition, Mapping):
        missing = [k for k in keys if k not in condition]
        if missing:
            raise DataFormatError(
                f"condition for {term!r} lacks key(s) {', '.join(missing)} "
                f"(the database uses {', '.join(keys)})"
            )
        cols = [_finite_values(term, k, condition[k]) for k in keys]
        # a database without keys is a constant per term: one row of no columns
        x = np.stack(np.broadcast_arrays(*cols), axis=-1) if cols else np.empty((1, 0))
    else:
        x = np.atleast_2d(_finite_values(term, "rows", condition))
    if x.shape[-1] != len(keys):
        raise DataFormatError(
            f"condition for {term!r} has {x.shape[-1]} columns, the database "
            f"uses {len(keys)} keys ({', '.join(keys)})"
        )
    return x


def _finite_values(term: str, key: str, values: Any) -> FloatArray:
    return finite_array(values, f"condition for {term!r}: {key}")


def grid_points(n: Any) -> int:
    """A grid's point count: two at least (a table of one breakpoint interpolates nothing)."""
    return whole_number(n, "n", DataFormatError, least=2)


def t_quantile(dof: float, p: float) -> float:
    """Student's t quantile (the normal's where no degree of freedom is left)."""
    if dof < 1.0:
        return norm_ppf(p)
    from scipy.special import stdtrit

    return float(stdtrit(dof, p))


def check_identifiable(
    term: str, es: Sequence[Exponents], u: FloatArray, flights: Sequence[str], keys: Sequence[str]
) -> None:
    a = design(u, es)
    if a.shape[0] < a.shape[1]:
        raise IdentificationError(
            f"{term!r}: the forced structure has {a.shape[1]} functions but only "
            f"{a.shape[0]} flight(s) excite it ({', '.join(flights)})"
        )
    sv = np.linalg.svd(a, compute_uv=False)
    if sv[-1] <= 1e-9 * max(sv[0], 1.0):
        flat = [k for i, k in enumerate(keys) if np.ptp(u[:, i]) <= 1e-9 and any(e[i] for e in es)]
        why = (
            f"condition {', '.join(flat)} does not vary over"
            if flat
            else "the conditions do not separate"
        )
        raise IdentificationError(
            f"{term!r} is unidentifiable: {why} the flights that excite it ({', '.join(flights)})"
        )
