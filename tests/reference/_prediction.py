"""Shared helpers of the SIDPAC prediction cases (not part of the library).

SIDPAC's text examples 5.1, 6.1 and 7.3 and its ``totter_tf_demo`` end by
flying the identified model on a second manoeuvre. The cases here put SIDPAC's
predicted outputs beside ours: per output the largest difference relative to
the measured output's range, and the prediction's fit (rms error and R²,
computed the same way from both predictions). SIDPAC's own simulation and
transform are written here in numpy, from the algorithms of its ``zep.m``,
``fint.m``/``ficor.m``, ``ulag.m``, ``ocf.m`` and ``tfsim.m`` (``lsims.m`` is
`_sidpac.lsims`), to tell a difference of the estimates from one of the
simulation.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import _sidpac as S
import numpy as np


def zep(x: Any) -> np.ndarray:
    """SIDPAC's zep: each column less the straight line through its end points."""
    x = np.asarray(x, dtype=float)
    ramp = np.linspace(0.0, 1.0, x.shape[0]).reshape((-1,) + (1,) * (x.ndim - 1))
    return np.asarray(x - (x[:1] + ramp * (x[-1:] - x[:1])), dtype=float)


def _weights(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cubic Fourier integral's correction factor and four end weights at
    ``theta = w dt`` (series below 0.1, where the closed form cancels)."""
    small = th < 0.1
    t = np.where(small, 0.5, th)  # the closed form only where it is used
    t2, t3, t4 = t * t, t**3, t**4
    c, cc, s, ss = np.cos(t), np.cos(2 * t), np.sin(t), np.sin(2 * t)
    k = 6.0 + t2
    cor = k / (3 * t4) * (3 - 4 * c + cc)
    alf = np.stack(
        [
            ((-42 + 5 * t2) + k * (8 * c - cc)) / (6 * t4)
            - 1j * ((-12 * t + 6 * t3) + k * ss) / (6 * t4),
            (14 * (3 - t2) - 7 * k * c) / (6 * t4) - 1j * (30 * t - 5 * k * s) / (6 * t4),
            (-4 * (3 - t2) + 2 * k * c) / (3 * t4) - 1j * (-12 * t + 2 * k * s) / (3 * t4),
            (2 * (3 - t2) - k * c) / (6 * t4) - 1j * (6 * t - k * s) / (6 * t4),
        ],
        axis=1,
    )
    u2, u4 = th * th, th**4
    u6 = u4 * u2
    ser_cor = 1 - 11 / 720 * u4 + 23 / 15120 * u6
    ser = np.stack(
        [
            -2 / 3 + u2 / 45 + 103 / 15120 * u4 - 169 / 226800 * u6
            - 1j * th * (2 / 45 + 2 / 105 * u2 - 8 / 2835 * u4 + 86 / 467775 * u6),
            7 / 24 - 7 / 180 * u2 + 5 / 3456 * u4 - 7 / 259200 * u6
            - 1j * th * (7 / 72 - u2 / 168 + 11 / 72576 * u4 - 13 / 5987520 * u6),
            -1 / 6 + u2 / 45 - 5 / 6048 * u4 + u6 / 64800
            - 1j * th * (-7 / 90 + u2 / 210 - 11 / 90720 * u4 + 13 / 7484400 * u6),
            1 / 24 - u2 / 180 + 5 / 24192 * u4 - u6 / 259200
            - 1j * th * (7 / 360 - u2 / 840 + 11 / 362880 * u4 - 13 / 29937600 * u6),
        ],
        axis=1,
    )  # fmt: skip
    return np.where(small, ser_cor, cor), np.where(small[:, None], ser, alf)


def fint(h: Any, t: Any, w: Any) -> np.ndarray:
    """SIDPAC's fint: the finite Fourier transform of `h` at `w` (rad/s) with the
    cubic end corrections of ficor (Numerical Recipes' dftint)."""
    h = np.asarray(h, dtype=float)
    t = np.asarray(t, dtype=float).ravel()
    w = np.asarray(w, dtype=float).ravel()
    dt = t[1] - t[0]
    k = np.arange(h.size)
    plain = np.exp(-1j * np.outer(w, k * dt)) @ h
    cor, alf = _weights(w * dt)
    ends = alf @ h[:4] + np.exp(-1j * w * (t[-1] - t[0])) * (np.conj(alf) @ h[::-1][:4])
    return np.asarray(dt * np.exp(-1j * w * t[0]) * (cor * plain + ends))


def ulag(u: Any, t: Any, tau: float) -> np.ndarray:
    """SIDPAC's ulag: the input delayed by `tau` (s), held at its first value before
    the record, linear between samples."""
    u = np.asarray(u, dtype=float).ravel()
    dt = float(t[1] - t[0])
    whole = int(abs(tau) / dt)
    frac = abs(tau) / dt - whole
    if tau < 0:
        raise ValueError("ulag: a negative delay is not used here")
    lag = np.concatenate([np.full(whole, u[0]), u[: u.size - whole]])
    lag1 = np.concatenate([np.full(whole + 1, u[0]), u[: u.size - whole - 1]])
    return np.asarray(lag + frac * (lag1 - lag))


def ocf(num: Any, den: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """SIDPAC's ocf: the observable canonical form of a strictly proper num/den."""
    den = np.asarray(den, dtype=float).ravel()
    num = np.asarray(num, dtype=float).ravel() / den[0]
    den = den / den[0]
    n = den.size - 1
    b = np.zeros(n)
    b[: num.size] = num[::-1]
    a = np.zeros((n, n))
    a[1:, :-1] = np.eye(n - 1)
    a[:, -1] = -den[:0:-1]
    c = np.zeros((1, n))
    c[0, -1] = 1.0
    return a, b[:, None], c, np.zeros((1, 1))


def tfsim(num: Any, den: Any, tau: float, u: Any, t: Any) -> np.ndarray:
    """SIDPAC's tfsim: `num`/`den` with delay `tau` from rest, by lsims' second-order step."""
    a, b, c, d = ocf(num, den)
    ul = ulag(u, t, tau)
    return S.lsims(a, b, c, d, ul[:, None], t, np.zeros(a.shape[0]))[:, 0]


def scipy_response(num: Any, den: Any, tau: float, u: Any, t: Any) -> np.ndarray:
    """A user's simulation of a fitted transfer function: scipy's exact response to
    the input interpolated linearly between samples, delayed by `tau`, from rest."""
    import scipy.signal

    t = np.asarray(t, dtype=float).ravel()
    late = np.interp(t - tau, t, np.asarray(u, dtype=float).ravel())
    return np.asarray(scipy.signal.lsim((num, den), late, t - t[0])[1], dtype=float)


def rms(x: Any) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def r_squared(measured: Any, predicted: Any) -> float:
    z = np.asarray(measured, dtype=float)
    e = z - np.asarray(predicted, dtype=float)
    return float(1.0 - e @ e / np.sum((z - z.mean()) ** 2))


def prediction_rows(
    case: str,
    names: Sequence[str],
    measured: Any,
    sidpac: Any,
    ours: Any,
    *,
    label: str = "",
    note: str | None = None,
    variant: bool = False,
) -> list[dict[str, Any]]:
    """Per output: ``<out> d/rng``, our prediction's largest difference from SIDPAC's
    over the measured output's range (``ours`` column; SIDPAC's blank), and both
    predictions' rms error (``<out> rms``) and R² (``<out> R2``)."""
    z = np.asarray(measured, dtype=float).reshape(len(measured), -1)
    ys = np.asarray(sidpac, dtype=float).reshape(z.shape)
    yo = np.asarray(ours, dtype=float).reshape(z.shape)
    rows = []
    for j, n in enumerate(names):
        span = float(np.ptp(z[:, j]))
        diff = float(np.max(np.abs(yo[:, j] - ys[:, j]))) / span
        kw: dict[str, Any] = {"sidpac_se_white": None, "sidpac_se_corrected": None}
        kw.update(ours_se=None, note=note, variant=variant)
        rows.append(S.row(case, f"{label}{n} d/rng", sidpac=None, ours=diff, **kw))
        rows.append(
            S.row(
                case,
                f"{label}{n} rms",
                sidpac=rms(z[:, j] - ys[:, j]),
                ours=rms(z[:, j] - yo[:, j]),
                **kw,
            )
        )
        rows.append(
            S.row(
                case,
                f"{label}{n} R2",
                sidpac=r_squared(z[:, j], ys[:, j]),
                ours=r_squared(z[:, j], yo[:, j]),
                **kw,
            )
        )
    return rows
