"""Finite Fourier transform of sampled signals at arbitrary frequencies.

``X(f) = Δt Σ_{i=0}^{N-1} x_i e^{-j 2π f t_i}`` with ``t_i = i Δt`` (the Euler
approximation of ``∫_0^T x(t) e^{-j 2π f t} dt``; Klein & Morelli, ch. 7).
Evenly spaced frequencies lie on a circular arc of the z-plane, where the
chirp-z transform (Rabiner, Schafer & Rader 1969) gives all of them in
O((N + M) log(N + M)) operations at any resolution, not only the FFT bins.
Fewer frequencies than about 16 log2(N + M), or unevenly spaced ones, are
summed directly, in blocks of about sqrt(N) samples: real matrix products
with views of the signals, and no (M, N) kernel in memory.
The chirp-z transform is Bluestein's (1970) convolution with `numpy.fft`, so
that no call imports `scipy.signal`, the slowest SciPy module to import.

With ``end_correction=True`` the sum becomes the trapezoidal rule: the two end
samples count half, which removes the O(Δt) error the Euler sum makes on a
record that does not start and end at zero. The fourth-order correction
(SIDPAC's cubic-interpolation finite Fourier integral: the exact transform of
the local cubic through four samples) is `aeroid.frequency.frequency_domain`'s
piecewise-cubic transform, built on this sum; it is not repeated here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import DataFormatError

__all__ = ["fourier", "hann"]

ComplexArray = NDArray[np.complex128]

# Evenly spaced frequencies go to the chirp-z transform from this many per log2 of the
# transform length: below it the block sum does less work (and rounds less).
_CZT_FROM = 16
# The direct sum's blocks hold (M, N / B) sums per signal; above this many elements the
# frequencies are split, which keeps the temporaries small enough for the allocator to
# reuse them rather than map fresh pages on every call.
_CHUNK = 1 << 16


def fast_length(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n: transform lengths `numpy.fft` does fastest."""
    best = 1 << max(0, (n - 1).bit_length())
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def hann(n: int) -> NDArray[np.float64]:
    """Periodic Hann window of `n` points (``scipy.signal.get_window("hann", n)``).

    ``w_i = 1/2 − 1/2 cos(2π i / n)``, evaluated as SciPy does (the first `n` points
    of a symmetric window of ``n + 1``), so the values are the same to the bit.
    """
    if n <= 1:
        return np.ones(max(n, 0))
    fac = np.linspace(-np.pi, np.pi, n + 1)[:-1]
    return np.asarray(0.5 + 0.5 * np.cos(fac), dtype=np.float64)


def _chirp_z(x: NDArray[np.float64], m: int, f0: float, df: float, dt: float) -> ComplexArray:
    """``Σ_i x_i e^{−j2π (f0 + k df) i Δt}`` for k < m, each column of `x` (n, c).

    Bluestein: ``ik = (i² + k² − (k − i)²) / 2`` turns the sum into the chirp
    ``e^{−jπ df Δt k²}`` times the convolution of ``x_i e^{−j2π f0 Δt i − jπ df Δt i²}``
    with ``e^{jπ df Δt l²}``, done by FFT.
    """
    n = x.shape[0]
    # i² mod 2/(df Δt) would be exact only for rational df Δt: i² stays an exact
    # integer (n < 2^26), so the phase error is the rounding of one product.
    half = np.pi * df * dt
    i = np.arange(n, dtype=np.float64)
    k = np.arange(m, dtype=np.float64)
    pre = np.exp(-1j * (2.0 * np.pi * f0 * dt * i + half * i * i))
    lags = np.arange(-(n - 1), m, dtype=np.float64)
    kern = np.exp(1j * half * lags * lags)
    size = fast_length(n + m - 1)
    spec = np.fft.fft(x * pre[:, None], size, axis=0)
    spec *= np.fft.fft(kern, size)[:, None]
    conv = np.fft.ifft(spec, axis=0)[n - 1 : n - 1 + m]
    return np.asarray(conv * np.exp(-1j * half * k * k)[:, None], dtype=np.complex128)


def _evenly_spaced(freq: NDArray[np.float64]) -> bool:
    if freq.size < 3:
        return False
    steps = np.diff(freq)
    return bool(steps[0] != 0 and np.ptp(steps) <= 1e-9 * abs(float(steps[0])))


def _kernel(freq: NDArray[np.float64], n: int, dt: float) -> ComplexArray:
    """``e^{-j 2π f t_i}`` (m, n) from ~2 sqrt(n) exponentials per frequency.

    Block b of B samples is the first block turned by ``e^{-j 2π f b B Δt}``: one
    complex product per element instead of a cosine and a sine.
    """
    block = max(1, int(np.sqrt(n)))
    n_blocks = -(-n // block)
    w = -2.0 * np.pi * freq[:, None] * dt
    first = np.exp(1j * w * np.arange(block)[None, :])  # (m, B)
    turns = np.exp(1j * w * block * np.arange(n_blocks)[None, :])  # (m, n_blocks)
    kern = (turns[:, :, None] * first[:, None, :]).reshape(freq.size, n_blocks * block)
    return np.asarray(kern[:, :n], dtype=np.complex128)


def _block_sum(x: NDArray[np.float64], freq: NDArray[np.float64], dt: float) -> ComplexArray:
    """``Σ_i x_i e^{-j 2π f i Δt}`` (m, c) for the columns of `x` (n, c), any frequencies.

    The record is cut into blocks of B ≈ sqrt(n) samples. Sample i of block b has
    the kernel ``e^{-j 2π f i Δt}`` of the first block turned by ``e^{-j 2π f b B Δt}``,
    so real products of the first block's cosine and sine rows (m, B) with each
    block (a view of `x`) sum within the blocks, and one turn per block and
    frequency sums the blocks. No (m, n) kernel and no copy of the record is
    made: fresh memory of that size costs more in page faults than the sums.
    """
    n, c = x.shape
    block = max(1, int(np.sqrt(n)))
    full = n // block
    blocks = x[: full * block].reshape(full, block, c)
    tail = x[full * block :]
    out = np.empty((freq.size, c), dtype=np.complex128)
    rows = max(1, _CHUNK // max(full * c, 1))
    for s in range(0, freq.size, rows):
        w = -2.0 * np.pi * freq[s : s + rows, None] * dt
        angle = w * np.arange(block)[None, :]
        wc = np.matmul(np.cos(angle), blocks)  # (blocks, m, c): the sums within blocks
        ws = np.matmul(np.sin(angle), blocks)
        turn = w * block * np.arange(full)[None, :]
        tc, ts = np.cos(turn), np.sin(turn)
        re = np.einsum("mb,bmc->mc", tc, wc) - np.einsum("mb,bmc->mc", ts, ws)
        im = np.einsum("mb,bmc->mc", tc, ws) + np.einsum("mb,bmc->mc", ts, wc)
        if tail.shape[0]:
            last = w * (full * block + np.arange(tail.shape[0]))[None, :]
            re += np.cos(last) @ tail
            im += np.sin(last) @ tail
        out[s : s + rows] = re + 1j * im
    return out


def fourier(
    signals: ArrayLike,
    dt: float,
    frequencies_hz: ArrayLike,
    *,
    end_correction: bool = False,
) -> ComplexArray:
    """Finite Fourier transform of each column of `signals` at `frequencies_hz`.

    Parameters
    ----------
    signals : array_like, shape (n,) or (n, k)
        Uniformly sampled signals, time along the first axis.
    dt : float
        Sample interval in seconds.
    frequencies_hz : array_like, shape (m,)
        Frequencies in Hz (any order, any spacing). Many evenly spaced ones
        are computed by the chirp-z transform, the others by a direct sum.
    end_correction : bool
        Trapezoidal end correction (half weight on the first and last samples).

    Returns
    -------
    ndarray of complex, shape (m,) or (m, k)
        ``Δt Σ x_i e^{-j 2π f t_i}``, matching the shape of `signals`.

    Raises
    ------
    DataFormatError
        On non-finite input, a non-positive `dt` or a bad frequency array.
    """
    x = np.asarray(signals, dtype=np.float64)
    one = x.ndim == 1
    if one:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] < 1:
        raise DataFormatError(f"signals: expected shape (n,) or (n, k), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DataFormatError("signals: non-finite values")
    step = float(dt)
    if not (np.isfinite(step) and step > 0.0):
        raise DataFormatError(f"dt: expected a positive sample interval, got {dt!r}")
    freq = np.atleast_1d(np.asarray(frequencies_hz, dtype=np.float64))
    if freq.ndim != 1 or not np.all(np.isfinite(freq)):
        raise DataFormatError("frequencies_hz: expected a 1-D array of finite frequencies")
    n, m = x.shape[0], freq.size
    if m == 0:
        out = np.zeros((0, x.shape[1]), dtype=np.complex128)
    elif _evenly_spaced(freq) and m > _CZT_FROM * np.log2(n + m):
        df = (float(freq[-1]) - float(freq[0])) / (m - 1)
        out = _chirp_z(x, m, float(freq[0]), df, step)
    else:
        out = _block_sum(x, freq, step)
    out = np.asarray(out, dtype=np.complex128) * step
    if end_correction and n >= 2:
        out -= trapezoid_ends(x[0], x[-1], freq, (n - 1) * step, step)
    return out[:, 0] if one else out


def trapezoid_ends(
    first: ArrayLike, last: ArrayLike, frequencies_hz: NDArray[np.float64], span: float, dt: float
) -> ComplexArray:
    """What the trapezoid rule takes off a plain sum's transform: half of the first
    and last samples (`span` seconds apart), shape (m,) or (m, k) as the samples."""
    back = np.exp(-2j * np.pi * frequencies_hz * span)
    a, b = np.asarray(first), np.asarray(last)
    if a.ndim:
        return np.asarray(0.5 * dt * (a[None, :] + back[:, None] * b[None, :]), dtype=np.complex128)
    return np.asarray(0.5 * dt * (a + back * b), dtype=np.complex128)
