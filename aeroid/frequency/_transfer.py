"""One transfer-function evaluator shared by the frequency-domain tools.

Every tool states a transfer function the same way: polynomial coefficients in
descending powers of s (``numpy.polyval`` order), an optional pure delay in seconds,
and frequencies in rad/s. A state-space model goes through `state_space_response`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

ComplexArray = NDArray[np.complex128]
FloatArray = NDArray[np.float64]


def transfer_at(
    numerator: ArrayLike, denominator: ArrayLike, s: ArrayLike, *, delay: float = 0.0
) -> ComplexArray:
    """N(s) / D(s) * exp(-delay s) at complex `s` (coefficients in descending powers)."""
    z = np.asarray(s, dtype=np.complex128)
    num = np.atleast_1d(np.asarray(numerator, dtype=np.float64))
    den = np.atleast_1d(np.asarray(denominator, dtype=np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.polyval(num, z) / np.polyval(den, z)
    if delay:
        out = out * np.exp(-float(delay) * z)
    return np.asarray(out, dtype=np.complex128)


def transfer_response(
    numerator: ArrayLike, denominator: ArrayLike, omega: ArrayLike, *, delay: float = 0.0
) -> ComplexArray:
    """T(jω) at frequencies ω in rad/s (coefficients in descending powers of s)."""
    w = np.asarray(omega, dtype=np.float64)
    return transfer_at(numerator, denominator, 1j * w, delay=delay)


def state_space_response(
    a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike, omega: ArrayLike
) -> ComplexArray:
    """C (jωI - A)^-1 B + D at each ω in rad/s, shape (n_ω, n_y, n_u)."""
    am = np.atleast_2d(np.asarray(a, dtype=np.float64))
    bm = np.atleast_2d(np.asarray(b, dtype=np.float64))
    cm = np.atleast_2d(np.asarray(c, dtype=np.float64))
    dm = np.atleast_2d(np.asarray(d, dtype=np.float64))
    w = np.atleast_1d(np.asarray(omega, dtype=np.float64))
    eye = np.eye(am.shape[0])
    lhs = 1j * w[:, None, None] * eye[None] - am[None]
    rhs = np.broadcast_to(bm.astype(np.complex128), (w.size, *bm.shape))
    x = np.linalg.solve(lhs, rhs)
    return np.asarray(cm[None] @ x + dm[None], dtype=np.complex128)
