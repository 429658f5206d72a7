"""What `propagate` draws from: a result's parameters, covariance and degrees of freedom
(or a posterior's rows), the block-wise draws, and what identifies a propagation's
source and metric so that `combine_batches` refuses a mix."""

from __future__ import annotations

import functools
import hashlib
import math
import types
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import as_float
from ..errors import PropagationError

FloatArray = NDArray[np.float64]

#: Draws are generated in blocks of this size, block b from
#: ``SeedSequence(seed, spawn_key=(b,))``, so the samples do not depend on how
#: a caller (such as the pipeline) splits the work into batches.
BLOCK_SIZE = 256
# A correlation matrix's eigenvalue below this is no rounding error: not a covariance.
_PSD_TOLERANCE = 1e-8


@dataclass(frozen=True)
class Source:
    """The distribution draws come from: ``rows`` (posterior samples) when ``cov`` is
    None, else the mean ``rows`` with covariance ``cov`` and per-parameter degrees of
    freedom ``dof`` (inf: normal)."""

    names: list[str]
    rows: FloatArray
    cov: FloatArray | None
    dof: FloatArray
    fixed: dict[str, float]

    @functools.cached_property
    def root(self) -> FloatArray:
        # eigh tolerates positive semi-definite covariances
        assert self.cov is not None
        w, v = np.linalg.eigh(0.5 * (self.cov + self.cov.T))
        return np.asarray(v * np.sqrt(np.clip(w, 0, None)), dtype=np.float64)

    @functools.cached_property
    def digest(self) -> str:
        """A short hash of everything the draws depend on (but the seed)."""
        h = hashlib.sha256()
        h.update(repr((self.names, sorted(self.fixed.items()))).encode())
        for arr in (self.rows, self.cov, self.dof):
            h.update(b"-" if arr is None else np.ascontiguousarray(arr).tobytes())
        return h.hexdigest()[:16]


def source(result: Any) -> Source:
    """The `Source` of an identification result, a fit with parameters and covariance
    (`TransferFunctionFit`, `EquivalentSystemFit`), or a posterior; else a
    `PropagationError` saying what is accepted."""
    names = list(getattr(result, "parameter_names", ()))
    fixed = {k: float(v) for k, v in dict(getattr(result, "fixed", {}) or {}).items()}
    samples = getattr(result, "samples", None)
    if samples is not None and np.ndim(samples) == 2:
        arr = np.asarray(samples, dtype=np.float64)
        if arr.shape[1] != len(names):
            raise PropagationError("posterior samples do not match parameter_names")
        return Source(names, arr, None, np.full(len(names), np.inf), fixed)
    cov_given = getattr(result, "covariance", None)
    params = getattr(result, "parameters", None)
    if not names and isinstance(params, Mapping) and cov_given is not None:
        names, cov_given, fixed = _fit_names(result, params, cov_given)
    if not names or cov_given is None:
        raise PropagationError(
            "propagate takes an IdentificationResult (or another estimator's result with "
            "parameter_names and a covariance), a TransferFunctionFit or "
            "EquivalentSystemFit (parameters and a covariance), or an InferenceResult "
            f"(posterior samples), got {type(result).__name__}"
        )
    mean = np.array([float(result.parameters[n]) for n in names])
    cov = np.asarray(cov_given, dtype=np.float64)
    if cov.shape != (len(names), len(names)):
        raise PropagationError(
            f"the covariance is {cov.shape}, its {len(names)} parameters need "
            f"({len(names)}, {len(names)})"
        )
    if not np.all(np.isfinite(cov)):
        raise PropagationError(
            "the covariance holds non-finite entries (unidentifiable parameters); "
            "fix or drop those parameters before propagating"
        )
    _check_covariance(names, cov)
    given = dict(getattr(result, "degrees_of_freedom", None) or {})
    dof = np.array([_dof(given.get(n)) for n in names])
    return Source(names, mean, cov, dof, fixed)


def _fit_names(
    result: Any, params: Mapping[str, Any], cov: Any
) -> tuple[list[str], Any, dict[str, float]]:
    """A fit's drawn names (its `stderr`'s, the covariance's order, that are parameters:
    an `EquivalentSystemFit`'s ``T_theta2`` is a function of ``1/T_theta2``), the
    covariance over them, and its other parameters, held fixed."""
    order = list(getattr(result, "stderr", None) or {})
    if np.shape(cov) != (len(order), len(order)):
        return [], None, {}
    keep = [i for i, n in enumerate(order) if n in params]
    names = [order[i] for i in keep]
    fixed = {k: float(v) for k, v in params.items() if k not in names}
    return names, np.asarray(cov, dtype=np.float64)[np.ix_(keep, keep)], fixed


def _dof(value: Any) -> float:
    """Degrees of freedom as `interval` reads them: the normal's (inf) where none is given."""
    nu = as_float(value)
    return nu if nu is not None and math.isfinite(nu) else math.inf


def _check_covariance(names: list[str], cov: FloatArray) -> None:
    variances = np.diag(cov)
    negative = [n for n, v in zip(names, variances, strict=True) if v < 0.0]
    if negative:
        raise PropagationError(
            f"the covariance gives {', '.join(negative)} a negative variance; "
            "it is no covariance (an edited or corrupted result?)"
        )
    # judged on the correlations: parameters of very different sizes do not hide it
    scale = np.sqrt(variances)
    scale[scale == 0.0] = 1.0
    corr = cov / np.outer(scale, scale)
    least = float(np.min(np.linalg.eigvalsh(0.5 * (corr + corr.T)))) if names else 0.0
    if least < -_PSD_TOLERANCE:
        raise PropagationError(
            "the covariance is not positive semi-definite (its correlation matrix has the "
            f"eigenvalue {least:.3g}); it is no covariance (an edited or corrupted result?)"
        )


def draws(src: Source, n_samples: int, seed: int | None, start: int) -> FloatArray:
    """Rows ``start .. start + n_samples`` of the stream of `seed`, block by block."""
    stop = start + n_samples
    out = np.empty((n_samples, len(src.names)))
    for block in range(start // BLOCK_SIZE, (stop - 1) // BLOCK_SIZE + 1):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(block,)))
        lo = block * BLOCK_SIZE
        if src.cov is None:
            rows = src.rows[rng.integers(0, src.rows.shape[0], BLOCK_SIZE)]
        else:
            gauss = rng.standard_normal((BLOCK_SIZE, len(src.names))) @ src.root.T
            rows = src.rows + _t_marginals(gauss, src.root, src.dof)
        a, b = max(start, lo), min(stop, lo + BLOCK_SIZE)
        out[a - start : b - start] = rows[a - lo : b - lo]
    return out


def _t_marginals(gauss: FloatArray, root: FloatArray, dof: FloatArray) -> FloatArray:
    """Gaussian copula, Student's t marginals: column j of the correlated normal draws
    `gauss` mapped through Phi and the inverse t with ``dof[j]`` degrees of freedom
    (floored at one, as `interval` floors them), at the same scale; columns of
    infinite degrees of freedom (and those of no spread) are left as drawn, bit for bit."""
    from scipy.special import ndtr, stdtrit

    scale = np.sqrt(np.sum(root * root, axis=1))
    turn = np.flatnonzero(np.isfinite(dof) & (scale > 0.0))
    if not turn.size:
        return gauss
    out = gauss.copy()
    for j in turn.tolist():
        z = gauss[:, j] / scale[j]
        # through the lower tail on both sides: Phi(z) rounds to 1 for z > 8
        out[:, j] = -np.sign(z) * stdtrit(max(float(dof[j]), 1.0), ndtr(-np.abs(z))) * scale[j]
    return out


_PLAIN = (type(None), bool, int, float, complex, str, bytes)


def _constant(value: Any, h: Any) -> None:
    """Feed what identifies one of a code object's constants (no memory addresses)."""
    if isinstance(value, types.CodeType):
        _code(value, h)
    elif isinstance(value, tuple):
        h.update(b"(")
        for v in value:
            _constant(v, h)
        h.update(b")")
    elif isinstance(value, frozenset):  # its order moves with the hash seed
        h.update(repr(sorted(repr(v) if isinstance(v, _PLAIN) else "?" for v in value)).encode())
    else:
        h.update((repr(value) if isinstance(value, _PLAIN) else type(value).__name__).encode())


def _code(code: types.CodeType, h: Any) -> None:
    h.update(code.co_code)
    h.update(repr(code.co_names).encode())
    for c in code.co_consts:
        _constant(c, h)


def metric_identity(func: Any) -> str:
    """``module.qualname#digest`` of a metric: its name and a hash of its bytecode,
    constants and closure values, the same in every process that loads the same code
    (a lambda's name alone would not tell two lambdas apart)."""
    inner = func.func if isinstance(func, functools.partial) else func
    target = inner if hasattr(inner, "__qualname__") else type(inner)
    name = f"{getattr(target, '__module__', '')}.{getattr(target, '__qualname__', '')}"
    h = hashlib.sha256(name.encode())
    code = getattr(inner, "__code__", None)
    if code is None and callable(inner):  # an object with __call__
        code = getattr(type(inner).__call__, "__code__", None)
    if isinstance(code, types.CodeType):
        _code(code, h)
    for cell in getattr(inner, "__closure__", None) or ():
        try:
            _constant(cell.cell_contents, h)
        except ValueError:  # an empty cell
            h.update(b"<empty>")
    if isinstance(func, functools.partial):
        _constant(func.args, h)
        _constant(tuple(sorted(func.keywords.items())), h)
    return f"{name}#{h.hexdigest()[:12]}"
