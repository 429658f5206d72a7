"""Cross-spectra of a composite frequency response: each window's spectral
matrix, its conditioning on several inputs, the random error and CIFER's
combination of the windows (see `aeroid.frequency.frequency_id`'s notes).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .._czt import _evenly_spaced, _kernel, fourier, hann
from ..errors import IdentificationError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

# A random error this small (γ² = 1 to rounding) still gives a finite weight.
_MIN_RANDOM_ERROR = 1e-9
# The least random error a composite reports: a windowed estimate of even a noise-free
# record is only good to about 1 % (leakage and resolution bias: the noise-free sweep
# of the tests), so no point claims less, and none outweighs a fit's others by more
# than (εr / 0.01)².
_RANDOM_ERROR_FLOOR = 0.01
# Bytes of segment transforms (or direct-sum kernel) held at once by `_window_spectra`.
_TRANSFORM_BUDGET = 1 << 27
# Smallest eigenvalue of the inputs' coherence matrix taken as singular.
_DEPENDENT = 1e-10


# -- spectra -----------------------------------------------------------------------------


def _independent_averages(n: int, seg: int, step: int, window: FloatArray) -> float:
    """Independent averages equivalent to K overlapped segments (Welch 1967)."""
    k = (n - seg) // step + 1
    shifts = np.arange(1, k) * step
    shifts = shifts[shifts < seg]
    w2 = float(np.dot(window, window))
    rho = np.array([np.dot(window[: seg - d], window[d:]) for d in shifts]) / w2
    lag = np.arange(1, shifts.size + 1)
    return float(k / (1.0 + 2.0 * np.sum((1.0 - lag / k) * rho**2)))


def _window_spectra(
    signals: FloatArray,
    dt: float,
    seg: int,
    step: int,
    omega: FloatArray,
    *,
    first_transforms: bool = False,
) -> tuple[ComplexArray, ComplexArray | None, float]:
    """Spectral matrix G[m, a, b] = E[conj(X_a) X_b] (one-sided density) of one window length,
    the first signal's segment transforms X (m, k) where asked for (else None) and the
    stationary count of independent averages."""
    n, c = signals.shape
    k = (n - seg) // step + 1
    win = hann(seg)
    g = np.zeros((omega.size, c, c), dtype=np.complex128)
    x0 = np.empty((omega.size, k), dtype=np.complex128) if first_transforms else None
    scale = 2.0 / (dt * float(np.dot(win, win)) * k)
    m = omega.size
    if _evenly_spaced(omega / (2.0 * np.pi)):
        # chirp-z on the windowed, mean-removed segments, a group of segments (and, for a
        # long window, a block of frequencies) at a time: a transform holds about three
        # arrays of (segment + frequencies) x signals, so a long record's many analysis
        # frequencies never hold every segment's transform at once
        per_segment = 48 * c * (seg + m)
        group = int(min(k, max(1, _TRANSFORM_BUDGET // per_segment)))
        block = (
            m
            if per_segment <= _TRANSFORM_BUDGET
            else max(1024, _TRANSFORM_BUDGET // (48 * c) - seg)
        )
        for first in range(0, k, group):
            starts = np.arange(first, min(k, first + group)) * step
            segs = signals[starts[:, None] + np.arange(seg)[None, :]]  # (kg, seg, c)
            segs = (segs - segs.mean(axis=1, keepdims=True)) * win[None, :, None]
            cols = np.ascontiguousarray(np.transpose(segs, (1, 0, 2)).reshape(seg, -1))
            for lo in range(0, m, block):
                part = omega[lo : lo + block]
                x = fourier(cols, dt, part / (2.0 * np.pi)).reshape(part.size, starts.size, c)
                g[lo : lo + block] += scale * np.einsum("mka,mkb->mab", np.conj(x), x)
                if x0 is not None:
                    x0[lo : lo + block, first : first + starts.size] = x[:, :, 0]
        return g, x0, _independent_averages(n, seg, step, win)
    # direct sum with the window folded into the kernel: the overlapping segments are
    # views of the record, and a segment's mean leaves as mean × W(ω)
    views = [np.lib.stride_tricks.sliding_window_view(signals[:, j], seg)[::step] for j in range(c)]
    blocks = [np.ascontiguousarray(v.T) for v in views]  # (seg, k) each
    means = [b.mean(axis=0) for b in blocks]
    block = max(1, min(m, _TRANSFORM_BUDGET // (48 * (seg + k * c))))
    for lo in range(0, m, block):
        part = omega[lo : lo + block]
        kern = _kernel(part / (2.0 * np.pi), seg, dt) * win[None, :]
        kr, ki = np.ascontiguousarray(kern.real), np.ascontiguousarray(kern.imag)
        w_sum = kern.sum(axis=1)
        x = np.empty((part.size, k, c), dtype=np.complex128)
        for j in range(c):
            x[:, :, j] = (kr @ blocks[j] + 1j * (ki @ blocks[j])) - w_sum[:, None] * means[j][
                None, :
            ]
        x *= dt
        g[lo : lo + block] = scale * np.einsum("mka,mkb->mab", np.conj(x), x)
        if x0 is not None:
            x0[lo : lo + block] = x[:, :, 0]
    return g, x0, _independent_averages(n, seg, step, win)


def _effective_averages(
    x: FloatArray | ComplexArray, omega: FloatArray, seg: int, step: int, dt: float
) -> FloatArray:
    """Independent averages behind a one-input estimate, per frequency, from the input's segments.

    ``Ĥ − H = Σ_k X̄_k N_k / Σ_k |X_k|²``; output noise in segments ``d`` samples apart
    correlates as ``E[N_k N̄_l] = S r_d e^{−jω d Δt}`` (``r_d`` the Hann window's overlap
    correlation), so ``Var Ĥ = S Q / (Σ |X_k|²)²`` with
    ``Q = Σ_{k,l} X̄_k X_l r_d e^{−jω d Δt}``; n_d = K Σ |X_k|² / Q makes it
    ``S / (n_d mean |X_k|²)``. A sweep puts each frequency in a few neighbouring,
    strongly overlapping segments, where the stationary count (Welch) would be far
    too many (and, where the overlap correlation changes sign, too few).
    """
    win = hann(seg)
    w2 = float(np.dot(win, win))
    power = np.sum(np.abs(x) ** 2, axis=1)  # (m,)
    q = power.copy()
    k = x.shape[1]
    for j in range(1, k):
        d = j * step
        if d >= seg:
            break
        r = float(np.dot(win[: seg - d], win[d:])) / w2
        lagged = np.sum(np.conj(x[:, :-j]) * x[:, j:], axis=1)
        q += 2.0 * r * np.real(lagged * np.exp(-1j * omega * d * dt))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = k * power / q
    return np.where(q > 0, np.maximum(out, 1.0), 1.0)


def _condition(g: ComplexArray, n_u: int) -> tuple[ComplexArray, FloatArray, FloatArray]:
    """H (m, n_u, n_y), partial coherence (m, n_u, n_y), multiple coherence (m, n_y)."""
    m, size, _ = g.shape
    n_y = size - n_u
    gxx = g[:, :n_u, :n_u]
    gxy = g[:, :n_u, n_u:]
    gyy = np.real(np.diagonal(g[:, n_u:, n_u:], axis1=1, axis2=2))
    with np.errstate(all="ignore"):
        if n_u == 1:
            pxx = np.real(gxx[:, 0, 0])
            h = gxy / pxx[:, None, None]
            coh = np.abs(gxy) ** 2 / (pxx[:, None, None] * gyy[:, None, :])
            mult = coh[:, 0, :].copy()
        else:
            h = np.linalg.pinv(gxx) @ gxy
            coh = np.empty((m, n_u, n_y))
            mult = np.empty((m, n_y))
            for j in range(n_y):
                idx = [*range(n_u), n_u + j]
                inv = np.linalg.pinv(g[:, idx][:, :, idx])
                giy = inv[:, :n_u, n_u]
                gii = np.real(np.diagonal(inv[:, :n_u, :n_u], axis1=1, axis2=2))
                gjj = np.real(inv[:, n_u, n_u])
                coh[:, :, j] = np.abs(giy) ** 2 / (gii * gjj[:, None])
                mult[:, j] = 1.0 - 1.0 / (gyy[:, j] * gjj)
    coh = np.clip(np.nan_to_num(coh, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    mult = np.clip(np.nan_to_num(mult, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    return np.nan_to_num(h), coh, mult


def _random_error(
    coh: FloatArray, n_d: FloatArray | float, n_u: int, *, floor: bool = True
) -> FloatArray:
    """Bendat & Piersol's ``sqrt(1 − γ²) / (|γ| sqrt(2 n_d))``, at least `_RANDOM_ERROR_FLOOR`.

    With the floor a point read at γ² = 1 weighs at most 10⁴ times a point of 100 %
    error in a fit, not 10¹⁸ (the old floor of 1e-9 let one such point decide a fit).
    Without it (`floor=False`) the error only ranks the windows of one frequency.
    """
    dof = np.maximum(np.asarray(n_d, dtype=np.float64) - n_u + 1.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt(1.0 - coh) / (np.sqrt(coh) * np.sqrt(2.0 * dof))
    least = _RANDOM_ERROR_FLOOR if floor else _MIN_RANDOM_ERROR
    return np.where(coh > 0.0, np.maximum(err, least), np.inf)


def _combine(spectra: ComplexArray, weights: FloatArray, n_u: int) -> ComplexArray:
    """Composite spectral matrix (m, c, c) of the windows' (n_w, m, c, c), weights (n_w, m).

    One weight per window and frequency for the whole matrix: a weighted mean of
    Hermitian, positive semi-definite matrices is one, so ``|Gxy|² <= Gxx Gyy`` and
    every coherence is at most 1 by construction (a weight per element, as a
    relative least-squares fit of each spectrum gives, broke that). Each window's
    matrix is first scaled by its inputs' power, so with one input the composite
    response is the weighted mean of the windows' responses.
    """
    power = np.mean(np.real(np.diagonal(spectra[:, :, :n_u, :n_u], axis1=2, axis2=3)), axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = np.where(power > 0, weights / power, 0.0)
    total = np.sum(scaled, axis=0)
    scaled = np.where(total > 0, scaled / np.where(total > 0, total, 1.0), weights)
    return np.asarray(np.einsum("wm,wmab->mab", scaled, spectra), dtype=np.complex128)


def _refuse_dependent_inputs(gxx: ComplexArray, names: Sequence[str]) -> None:
    """Refuse inputs whose cross-spectral matrix is singular at every frequency.

    Then one input is a combination (or a filtered copy) of the others and no
    conditioning can tell their responses apart: ``Gxx⁻¹`` does not exist and a
    pseudo-inverse would split the response between them arbitrarily.
    """
    d = np.sqrt(np.real(np.diagonal(gxx, axis1=1, axis2=2)))
    with np.errstate(all="ignore"):
        r = np.nan_to_num(gxx / (d[:, :, None] * d[:, None, :]))
    lam, vec = np.linalg.eigh(r)
    # exactly dependent inputs reach 1e-16 (rounding); a noise-free filtered copy 1e-3
    if np.all(lam[:, 0] <= _DEPENDENT):
        share = np.mean(np.abs(vec[:, :, 0]) ** 2, axis=0)
        involved = [n for n, v in zip(names, share, strict=True) if v > 0.01]
        raise IdentificationError(
            f"inputs {involved} are linearly dependent: their cross-spectral matrix is "
            "singular at every frequency (one is a multiple, combination or filtered copy "
            "of the others, or the windows hold too few segments to separate them), so "
            "their responses cannot be told apart; drop one of them"
        )
