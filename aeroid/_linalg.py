"""Small dense linear algebra in plain numpy (internal).

`scipy.linalg` costs a few tenths of a second to import (mostly its array-API
compatibility layer), more than a whole warm filter pass, so the matrix
exponential the exact discretisations need is computed here: scaling and
squaring with the degree-13 Padé approximant (Higham 2005), the scaling chosen
from the norms of powers of the matrix as in Al-Mohy & Higham (2009) so that
non-normal (stiff) matrices are not over-scaled. Batched over leading axes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Padé(13) coefficients b_0..b_13 of exp and the largest 2^-s A norm for which the
# approximant is accurate to double precision (Higham 2005, table 2.3).
_B13 = (
    64764752532480000.0,
    32382376266240000.0,
    7771770303897600.0,
    1187353796428800.0,
    129060195264000.0,
    10559470521600.0,
    670442572800.0,
    33522128640.0,
    1323241920.0,
    40840800.0,
    960960.0,
    16380.0,
    182.0,
    1.0,
)
_THETA13 = 5.371920351148152


def _norm1(X: FloatArray) -> FloatArray:
    """1-norm (largest absolute column sum) of each matrix of a stack."""
    out: FloatArray = np.max(np.sum(np.abs(X), axis=-2), axis=-1)
    return out


def expm(A: FloatArray) -> FloatArray:
    """Matrix exponential of a square matrix or a stack of them (..., n, n).

    A member with a non-finite entry gives NaN (every entry), never an error.
    """
    A = np.asarray(A, dtype=np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"expm needs square matrices, got shape {A.shape}")
    shape = A.shape
    n = shape[-1]
    X = A.reshape(-1, n, n)
    finite = np.all(np.isfinite(X), axis=(1, 2))
    if not np.all(finite):
        X = np.where(finite[:, None, None], X, 0.0)
    eye = np.eye(n)
    with np.errstate(all="ignore"):
        A2 = X @ X
        A4 = A2 @ A2
        A6 = A4 @ A2
        n1 = _norm1(X)
        if np.all(n1 <= _THETA13):  # no scaling needed (the usual A h of a discretisation)
            s = np.zeros(n1.shape, dtype=np.int64)
        else:
            # ||A^k||^(1/k) bounds the Padé error more tightly than ||A||^k for non-normal A
            d6 = _norm1(A6) ** (1.0 / 6.0)
            d8 = _norm1(A4 @ A4) ** (1.0 / 8.0)
            d10 = _norm1(A4 @ A6) ** (1.0 / 10.0)
            # fmin/fmax: an overflowed power (inf, or NaN from inf * 0) leaves the 1-norm
            eta = np.fmin(np.fmin(np.fmax(d6, d8), np.fmax(d8, d10)), n1)
            # the power norms can underflow to 0 while ||A|| does not
            eta = np.maximum(eta, n1 * 2.0**-53)
            s = np.where(
                eta > _THETA13, np.ceil(np.log2(np.maximum(eta, 1e-300) / _THETA13)), 0.0
            ).astype(np.int64)
    s = np.clip(s, 0, 1074)
    if np.any(s):
        # powers of the scaled matrix afresh: those of A may have overflowed
        X = X * np.ldexp(1.0, -s)[:, None, None]
        A2 = X @ X
        A4 = A2 @ A2
        A6 = A4 @ A2
    b = _B13
    U = X @ (
        A6 @ (b[13] * A6 + b[11] * A4 + b[9] * A2) + b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * eye
    )
    V = A6 @ (b[12] * A6 + b[10] * A4 + b[8] * A2) + b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * eye
    E = np.linalg.solve(V - U, V + U)
    smax = int(s.max()) if s.size else 0
    with np.errstate(all="ignore"):  # an exponential too large for a double is inf, as in scipy
        for i in range(smax):
            sel = s > i
            if np.all(sel):
                E = E @ E
            else:
                E[sel] = E[sel] @ E[sel]
    if not np.all(finite):
        E[~finite] = np.nan
    return np.asarray(E, dtype=np.float64).reshape(shape)


def information_inverse(info: FloatArray, rcond: float = 1e-13) -> FloatArray:
    """The pseudo-inverse of an information matrix scaled to a unit diagonal first.

    Parameters of very different sizes (a gain of 1e-6 beside a pole of 1) make the
    unscaled matrix's condition number their ratio squared: a relative cut of the
    singular values at `rcond` would then drop a well determined direction and report
    its variance as (nearly) zero. Scaled, the cut sees only the correlations.
    Unknowns with no information (zero diagonal) keep a zero row and column.
    """
    d = np.sqrt(np.clip(np.diag(info), 0.0, None))
    scale = np.where(d > 0.0, d, 1.0)
    with np.errstate(invalid="ignore"):  # an overflowed information: NaN, said by the caller
        unit = info / np.outer(scale, scale)
    if not np.all(np.isfinite(unit)):
        return np.full_like(unit, np.nan)
    inv = np.linalg.pinv(unit, rcond=rcond, hermitian=True) / np.outer(scale, scale)
    return np.asarray(inv, dtype=np.float64)


def information_basis(
    sensitivities: list[FloatArray], rcond: float
) -> tuple[list[FloatArray], FloatArray]:
    """An orthonormal basis of the sensitivities' span and the map from it to the
    parameters: ``G M^+ = U T`` per record, with ``M = sum G'G`` and ``M^+`` the
    pseudo-inverse `information_inverse` takes with cut `rcond`.

    Sandwich estimators need the fit's projection ``H = G M^+ G'``; formed from
    ``M^+``, near-collinear sensitivities make its entries huge and their sums
    cancel, losing ``eps cond(M)`` of every leverage (all of it at a condition
    number of 1e16). From the singular vectors of the column-scaled stacked
    sensitivities ``H = U U'`` exactly, and ``T = S^-1 V' D^-1`` carries the
    parameters' own directions, so a sandwich over ``U`` holds every digit
    the conditioning leaves. Returns each record's ``U`` (n_t, n_y, r) and
    ``T`` (r, p).
    """
    p = sensitivities[0].shape[2]
    stacked = np.concatenate([g.reshape(-1, p) for g in sensitivities])
    d = np.sqrt(np.einsum("ij,ij->j", stacked, stacked))
    d = np.where(d > 0.0, d, 1.0)
    q, r = np.linalg.qr(stacked / d)
    ur, s, vt = np.linalg.svd(r)
    keep = s**2 > rcond * s[0] ** 2 if s.size and s[0] > 0 else np.zeros(s.size, bool)
    keep &= s > 0.0
    u = q @ ur[:, keep]
    to_params = vt[keep] / s[keep, None] / d[None, :]
    cuts = np.cumsum([g.shape[0] for g in sensitivities])[:-1]
    out = [
        np.asarray(part.reshape(g.shape[0], g.shape[1], -1), dtype=np.float64)
        for part, g in zip(
            np.split(u, cuts * sensitivities[0].shape[1]), sensitivities, strict=True
        )
    ]
    return out, np.asarray(to_params, dtype=np.float64)
