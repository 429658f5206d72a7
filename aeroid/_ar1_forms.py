"""AR(1) covariances in closed form: the low band's bilinear forms of the
coloured-residual sandwich (`aeroid._colour`), without arrays of the record's length."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def geometric(r: NDArray[np.complex128], count: int) -> NDArray[np.complex128]:
    """``sum_{k=1}^{count} r^k`` elementwise, for ``|r| < 1``."""
    return np.asarray(r * (1.0 - r**count) / (1.0 - r), dtype=np.complex128)


def ar1_bilinear(
    w: FloatArray, n: int, a: float, var: float, *, conjugate: bool
) -> NDArray[np.complex128]:
    """``d_l' S d_m^*`` (or ``d_l' S d_m`` with `conjugate`), (bins l, bins m), for the
    AR(1) covariance ``S_ts = var a^|t-s|`` over n samples and the Fourier vectors
    ``d_l = e^{-i w_l t}``, in closed form: with ``x = e^{-i w_l}``, ``y = e^{+-i w_m}``
    and ``z = x y`` the double sum ``sum_ts x^t y^s a^|t-s|`` is the diagonal
    ``sum_t z^t`` plus, for each side, ``sum_{k=1}^{n-1} (xa)^k sum_{s<n-k} z^s``,
    each a geometric series (arithmetico-geometric where ``z = 1``). No array of the
    record's length: a long record's low band costs what a short one's does."""
    x = np.exp(-1j * w)[:, None]
    y = np.exp((-1j if conjugate else 1j) * w)[None, :]
    z = x * y
    one = np.abs(1.0 - z) < 1e-12
    zs = np.where(one, -1.0 + 0j, z)  # where z = 1 the closed form below is taken
    zn = zs**n
    last = n - 1

    def side(r: NDArray[np.complex128]) -> NDArray[np.complex128]:
        # sum_{k=1}^{n-1} r^k (1 - z^(n-k)) / (1 - z), or r^k (n - k) where z = 1
        spread = (geometric(r, last) - zn * geometric(r / zs, last)) / (1.0 - zs)
        ramp = (
            n * geometric(r, last)
            - r * (1.0 - (last + 1) * r**last + last * r ** (last + 1)) / (1.0 - r) ** 2
        )
        return np.asarray(np.where(one, ramp, spread), dtype=np.complex128)

    diagonal = np.where(one, float(n), (1.0 - zn) / (1.0 - zs))
    return np.asarray(var * (diagonal + side(x * a) + side(y * a)), dtype=np.complex128)
