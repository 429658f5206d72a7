"""The least-squares core of equation error: QR or normal equations, collinearity.

Split out of `aeroid.regression` (which re-exports every name).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .errors import DataFormatError, IdentificationError

FloatArray = NDArray[np.float64]

# A regressor whose part independent of the earlier ones is below this fraction of its
# own norm is a linear combination of them to working precision.
_COLLINEAR = 1e-9
# Below this 1 - R^2 of a regressor on the others (condition number of the scaled
# Gram matrix above ~1e10) the normal equations lose digits; QR is used instead.
_WELL_POSED = 1e-8


def _collinear(names: Sequence[str], j: int) -> IdentificationError:
    return IdentificationError(
        f"regressor {names[j]!r} is zero or a linear combination of "
        f"{list(names[:j]) or 'nothing'}; drop it or the regressors it repeats"
    )


def _qr_solve(x: FloatArray, z: FloatArray, names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
    """Least-squares parameters and (X'X)^-1 by Householder QR; refuses collinear columns."""
    q, r = np.linalg.qr(x)
    norms = np.linalg.norm(x, axis=0)
    diag = np.abs(np.diag(r))
    for j in range(x.shape[1]):
        if not diag[j] > _COLLINEAR * norms[j] or norms[j] == 0:
            raise _collinear(names, j)
    # R is only p x p: a plain inverse is cheaper here than LAPACK's triangular solver
    r_inv = np.linalg.inv(r)
    theta = r_inv @ (q.T @ z)
    return theta, r_inv @ r_inv.T


def _ls_solve(
    x: FloatArray, z: FloatArray, names: Sequence[str]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Least-squares parameters, (X'X)^-1 and X'X.

    Normal equations on the column-scaled Gram matrix with one step of iterative
    refinement: forming X'X costs a fraction of a QR factorisation of the tall
    matrix, and the refinement step brings the estimate to QR accuracy while the
    scaled matrix is well conditioned. Near-collinear columns go to QR.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # reported below, by name
        gram = x.T @ x
    d = np.sqrt(np.diag(gram))
    for j in np.flatnonzero(~np.isfinite(d)).tolist():
        raise DataFormatError(
            f"regressor {names[j]!r}: its sum of squares overflows; rescale it (units?)"
        )
    for j in np.flatnonzero(~(d > 0)).tolist():
        raise _collinear(names, j)
    scaled = gram / np.outer(d, d)
    try:
        chol = np.linalg.cholesky(scaled)
    except np.linalg.LinAlgError:
        return (*_qr_solve(x, z, names), gram)
    # the squared pivot is 1 - R^2 of a column on the ones before it
    if float(np.min(np.diag(chol))) ** 2 < _WELL_POSED:
        return (*_qr_solve(x, z, names), gram)
    l_inv = np.linalg.inv(chol)
    xtx_inv = (l_inv.T @ l_inv) / np.outer(d, d)
    theta = xtx_inv @ (x.T @ z)
    theta = theta + xtx_inv @ (x.T @ (z - x @ theta))
    return theta, xtx_inv, gram


def _reml_covariance(
    x: FloatArray, v: FloatArray, xtx_inv: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Output error's coloured-residual covariance for this one-output regression: the
    residual as AR(1) plus white noise by REML, with Satterthwaite's degrees of freedom
    (`_output_error`)."""
    from ._noise_model import _colored_covariance as output_error_covariance

    cov, _, nu = output_error_covariance([x[:, None, :]], [v[:, None]], np.ones(1), xtx_inv)
    return cov, nu


def _gram_stats(
    gram: FloatArray, szz: float, model: list[int]
) -> tuple[float, FloatArray | None, FloatArray | None]:
    """SSE of a model from the cross-products, its parameters and (X'X)^-1 block."""
    if not model:
        return szz, None, None
    g = gram[np.ix_(model, model)]
    b = gram[model, -1]
    try:
        ginv = np.linalg.inv(g)
    except np.linalg.LinAlgError:
        return szz, None, None
    theta = np.asarray(ginv @ b, dtype=np.float64)
    return max(szz - float(b @ theta), 0.0), theta, np.asarray(ginv, dtype=np.float64)
