"""The finite record's kernel: what the Fourier transforms of a record share.

Transforms at frequencies ``2 pi/T`` apart on a record ``T`` seconds long (the
``k/T`` grid) carry independent pieces of its noise. Frequencies packed closer
(SIDPAC's examples space them 0.04 Hz apart on 20-s records; the recursive
estimator's first updates see records of a few seconds) share it: for noise
whose spectrum is flat across a few bins ``E[e_j e_k^H] = kappa_jk S`` with
``kappa_jk = e^{-i dw T/2} sinc(dw T/2)``. `aeroid._colour.frequency_sandwich`
counts that in its meat (`overlap_terms`) and in what the fit left of each
residual (`kept_off_grid`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Elements of one block of the frequency-pair kernel's products (memory, not speed).
_KERNEL_BLOCK = 2_000_000


def off_grid(omega: FloatArray, span: float) -> tuple[FloatArray, float] | None:
    """``(omega, span)`` when the frequencies (rad/s) are not distinct points of the
    ``k/span`` grid of a record `span` seconds long (their transforms then share
    the noise: `aeroid._colour.frequency_sandwich` counts it), else None."""
    omega = np.asarray(omega, dtype=np.float64)
    bins = (omega - omega[0]) * span / (2 * np.pi)
    whole = np.round(bins)
    if np.max(np.abs(bins - whole), initial=0.0) < 1e-6 and np.unique(whole).size == whole.size:
        return None
    return omega, float(span)


def record_kernel(omega: FloatArray, rows: slice, span: float) -> NDArray[np.complex128]:
    """Rows `rows` of the white-noise transforms' correlation ``kappa``, its diagonal
    (a frequency with itself) set to zero."""
    half = 0.5 * (omega[rows, None] - omega[None, :]) * span
    kappa = np.exp(-1j * half) * np.sinc(half / np.pi)
    idx = np.arange(omega.size)[rows]
    kappa[np.arange(idx.size), idx] = 0.0
    return np.asarray(kappa, dtype=np.complex128)


def kept_off_grid(jac: FloatArray, m_inv: FloatArray, omega: FloatArray, span: float) -> FloatArray:
    """Per frequency, the share of the noise the fit leaves in its residual where the
    transforms share their noise: the diagonal blocks of ``(I - H) K (I - H)``, ``H =
    J M^-1 J'`` the hat matrix of the stacked real rows and ``K`` the transforms'
    correlation over a locally flat spectrum (``kappa`` as a complex product on each
    frequency's real and imaginary rows, one on the diagonal). On the grid ``K = I``
    and it is ``I - L``; off it, frequencies packed closer than the record resolves
    hold fewer independent pieces of noise than rows, and the fit takes a larger
    share of each than its own leverage says (a short record, in the first updates of
    the recursive estimator, most of all)."""
    m, rows, p = jac.shape
    r = rows // 2
    W = jac[:, :r] + 1j * jac[:, r:]  # (M, r, p)
    flat = W.reshape(m, r * p)
    mixed = np.empty_like(flat)
    step = max(1, _KERNEL_BLOCK // max(m, 1))
    for lo in range(0, m, step):
        block = slice(lo, min(lo + step, m))
        mixed[block] = record_kernel(omega, block, span) @ flat
    kw = W + mixed.reshape(m, r, p)  # (K J)_m as complex rows, the self term included
    kj = np.concatenate([kw.real, kw.imag], axis=1)  # (M, 2r, p)
    gram = np.einsum("mrp,mrq->pq", jac, kj)  # J' K J
    a = jac @ m_inv  # J_m M^-1, so (H K)_mm = A_m (K J)_m' and (H K H)_mm = A_m J'KJ A_m'
    hk = np.einsum("mrq,msq->mrs", a, kj)
    hkh = np.einsum("mrq,mtq->mrt", a @ gram, a)
    kept = np.eye(rows)[None] - hk - hk.transpose(0, 2, 1) + hkh
    return np.asarray(0.5 * (kept + kept.transpose(0, 2, 1)), dtype=np.float64)


def overlap_terms(
    W: NDArray[np.complex128],
    S: NDArray[np.complex128],
    AS: NDArray[np.complex128],
    omega: FloatArray,
    span: float,
) -> tuple[FloatArray, FloatArray]:
    """The meat's pairs ``sum_{j != k} 1/2 Re W_j^H kappa_jk S_jk W_k`` with ``S_jk =
    (S_j + S_k)/2``, and the pairs' share ``sum_{j != k} |kappa_jk|^2 tr(A_j S_j A_k
    S_k)`` of each variance estimate's variance (`AS` holds ``A_k S_k`` per
    parameter); ``kappa`` is formed a block of rows at a time, so memory stays
    linear in the frequencies.

    ``kappa`` is Hermitian, so the ``S_k`` half of the sum is the conjugate
    transpose of the ``S_j`` half, ``H = sum_jk kappa_jk W_j^H S_j W_k``: the
    pairs are ``Re(H + H^H) / 4``."""
    m, r, p = W.shape
    n_par = AS.shape[1]  # W may span the parameters through another basis
    left = (W.conj().transpose(0, 2, 1) @ S).transpose(1, 0, 2)  # W_j^H S_j, (p, M, r)
    flat_w = W.reshape(m, r * p)
    flipped = AS.swapaxes(-1, -2).reshape(m, -1)  # A_k S_k transposed, flattened
    half = np.zeros((p, p), dtype=np.complex128)
    pairs = np.zeros(n_par)
    step = max(1, _KERNEL_BLOCK // max(m + r * r * p, 1))
    for lo in range(0, m, step):
        rows = slice(lo, min(lo + step, m))
        kappa = record_kernel(omega, rows, span)  # (rows, M)
        n_rows = kappa.shape[0]
        mixed = (kappa @ flat_w).reshape(n_rows * r, p)  # sum_k kappa_jk W_k
        half += left[:, rows].reshape(p, n_rows * r) @ mixed
        spread = (np.abs(kappa) ** 2) @ flipped  # sum_k |kappa_jk|^2 (A_k S_k)'
        pairs += (
            (AS[rows].reshape(n_rows, -1) * spread).reshape(n_rows, n_par, -1).sum(axis=(0, 2)).real
        )
    out = 0.25 * (half + half.conj().T).real
    return np.asarray(out, dtype=np.float64), pairs
