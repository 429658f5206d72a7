"""FVSysID's least-squares preprocessing of the ATTAS records, in numpy (test code).

Jategaonkar, *Flight Vehicle System Identification* (2nd ed.), chapters 6 and 7:
the three ATTAS manoeuvres (elevator, aileron, rudder) are joined, the force and
moment coefficients are computed from the measured accelerations and rates
(umr_reg_attas.m), with the book's fixed smoother (smoothMulTS.m) and its
17-point differentiator (ndiff_Filter08.m) applied per manoeuvre, and each
coefficient is regressed by ordinary least squares (LS_Stat.m for the standard
deviations) or recursively with a forgetting factor (RLSff.m). Written here
from the method's description, not translated line by line.
"""

from __future__ import annotations

import pathlib
from collections.abc import Callable
from typing import Any

import _sidpac as S
import numpy as np

FILES = ("fAttasElv1.mat", "fAttasAil1.mat", "fAttasRud1.mat")
DT = 0.04
D2R = np.pi / 180.0

# ATTAS mass and geometry (umr_reg_attas.m)
MASS = 17631.0
IX, IY, IZ, IXZ = 1.33367e05, 2.52687e05, 3.59593e05, 1.14420e04
SREF, CREF, BREF = 64.0, 3.159, 10.75  # m^2; chord; HALF the span (the book's b)
AC = (-0.02, -0.01, -0.12)  # moment reference point from the CG, m
ACCEL = (-1.010, 0.886, 0.103)  # accelerometer from the CG, m
ENGINE = (-1.343, 2.990, -0.652)  # engine from the CG, m
NOSEBOOM = (13.080, -0.010, -0.027)  # air-data boom from the CG, m

# measurement biases of ax, ay, az (m/s^2), p, q, r (rad/s) the book subtracts: chapter 6
# uses the 2nd edition's (OEM with biases and initial conditions), chapter 7 the 1st's
BIASES = {
    2: (6.76242e-3, -1.50664e-3, 8.39892e-2, 1.02555e-3, 3.40891e-3, 9.96192e-4),
    1: (9.23669e-3, 2.09408e-4, 9.60082e-2, 1.08375e-3, 3.33630e-3, 1.00300e-3),
}

# the book's smoother: 15 points inside, 5 near the ends, the end three kept
_SMOOTH15 = np.array([-3, -6, -5, 3, 21, 46, 67, 74, 67, 46, 21, 3, -5, -6, -3]) / 320.0
_SMOOTH5 = np.array([7, 24, 34, 24, 7]) / 96.0
# the book's differentiator: antisymmetric weights on x(k+j) - x(k-j), j = 1..8
_DIFF8 = np.array(
    [
        0.88888888887637,
        -0.31111111109862,
        0.11313131312500,
        -0.03535353535135,
        0.00870240870185,
        -0.00155400155390,
        0.00017760017759,
        -0.00000971250971,
    ]
)
_DIFF2 = np.array([0.66666666666667, -0.08333333333333])


def segments(bounds: np.ndarray) -> list[slice]:
    """The manoeuvres of the joined record from their end indices (exclusive)."""
    starts = np.concatenate([[0], bounds[:-1]])
    return [slice(int(a), int(b)) for a, b in zip(starts, bounds, strict=True)]


def _fir(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Centred correlation with `kernel` (odd length), valid part only."""
    return np.correlate(x, kernel, mode="valid")


def smooth_book(x: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """smoothMulTS: per manoeuvre, the 15-point smoother where it fits, the 5-point one
    on the 5 samples nearer the ends, the 3 end samples unchanged."""
    out = np.array(x, dtype=float)
    for seg in segments(bounds):
        v = np.asarray(x[seg], dtype=float)
        n = v.size
        y = v.copy()
        y[2 : n - 2] = _fir(v, _SMOOTH5)
        y[8 : n - 8] = _fir(v, _SMOOTH15)[1:-1]
        y[:3], y[n - 3 :] = v[:3], v[n - 3 :]
        out[seg] = y
    return out


def _central(v: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """sum_j w_j (v[k+j] - v[k-j]) for every k with the whole stencil inside."""
    return _fir(v, np.concatenate([-weights[::-1], [0.0], weights]))


def diff_book(x: np.ndarray, bounds: np.ndarray, dt: float = DT) -> np.ndarray:
    """ndiff_Filter08: per manoeuvre, the 17-point derivative inside, the 5-point one on
    the 7 samples nearer each end, the end two copied from the third."""
    out = np.zeros(len(x))
    for seg in segments(bounds):
        v = np.asarray(x[seg], dtype=float)
        n = v.size
        y = np.zeros(n)
        y[2 : n - 2] = _central(v, _DIFF2)
        y[9 : n - 9] = _central(v, _DIFF8)[1:-1]
        y[:2], y[n - 2 :] = y[2], y[n - 3]
        out[seg] = y / dt
    return out


def load(folder: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """The three manoeuvres joined (columns as the README lists them, from 0) and
    the end index of each."""
    paths = S.need(folder, *FILES, source="fvsysid")
    parts = [np.asarray(S.loadmat(p)[p.stem], dtype=float) for p in paths]
    return np.vstack(parts), np.cumsum([len(p) for p in parts])


def book_rate_derivative(x: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """umr_reg_attas's angular acceleration: the book's smoother, then its differentiator."""
    return diff_book(smooth_book(x, bounds), bounds)


Segmentwise = Callable[[np.ndarray, np.ndarray], np.ndarray]


def preprocess(
    data: np.ndarray,
    bounds: np.ndarray,
    edition: int = 2,
    *,
    smoother: Segmentwise = smooth_book,
    rate_derivative: Segmentwise = book_rate_derivative,
) -> dict[str, np.ndarray]:
    """umr_reg_attas for the ATTAS test case 23, then the book's normalisation of the
    rates (`smoother` and `rate_derivative` swap the book's filters for others, each
    called as ``f(x, bounds)``): the coefficients (CD, CL, Cm, CY, Cl, Cn at the moment reference point) and
    the regressors (alpha, beta, V at the CG smoothed; pn, qn, rn from the measured
    rates, their biases NOT removed, as the book's scripts do; de, da, dr in rad)."""
    bax, bay, baz, bp, bq, br = BIASES[edition]
    ax, ay, az = data[:, 1] - bax, data[:, 2] - bay, data[:, 3] - baz
    pm, qm, rm = data[:, 6] * D2R, data[:, 7] * D2R, data[:, 8] * D2R
    p, q, r = pm - bp, qm - bq, rm - br
    al_nb, be_nb, v_nb = data[:, 12] * D2R, data[:, 13] * D2R, data[:, 14]
    rho = data[:, 33]
    thrust_l, thrust_r = data[:, 36], data[:, 37]
    # flow at the CG from the boom's: velocity components less omega x r_boom
    xb, yb, zb = NOSEBOOM
    u = v_nb * np.cos(be_nb) * np.cos(al_nb) + yb * r - zb * q
    v = v_nb * np.sin(be_nb) + zb * p - xb * r
    w = v_nb * np.cos(be_nb) * np.sin(al_nb) + xb * q - yb * p
    vt = np.sqrt(u * u + v * v + w * w)
    al = smoother(np.arctan(w / u), bounds)
    be = smoother(np.arcsin(v / vt), bounds)
    vt = smoother(vt, bounds)
    qbar = 0.5 * rho * vt * vt
    pd, qd, rd = (rate_derivative(s, bounds) for s in (p, q, r))
    # specific force at the CG from the accelerometer's (rates unsmoothed)
    xa, ya, za = ACCEL
    ax_cg = ax + xa * (q * q + r * r) - ya * (p * q - rd) - za * (p * r + qd)
    ay_cg = ay - xa * (p * q + rd) + ya * (r * r + p * p) - za * (q * r - pd)
    az_cg = az - xa * (p * r - qd) - ya * (q * r + pd) + za * (p * p + q * q)
    f_sum, f_diff = thrust_l + thrust_r, thrust_l - thrust_r
    qs = qbar * SREF
    cx = (MASS * ax_cg - f_sum) / qs
    cy = MASS * ay_cg / qs
    cz = MASS * az_cg / qs
    cd = -cx * np.cos(al) - cz * np.sin(al)
    cl = cx * np.sin(al) - cz * np.cos(al)
    roll = (IX * pd - IXZ * rd - IXZ * p * q - (IY - IZ) * q * r) / (qs * BREF)
    pitch = (IY * qd + (p * p - r * r) * IXZ - p * r * (IZ - IX) - f_sum * ENGINE[2]) / (qs * CREF)
    yaw = (IZ * rd - IXZ * pd + IXZ * q * r - (IX - IY) * p * q - f_diff * ENGINE[1]) / (qs * BREF)
    xr, yr, zr = AC
    return {
        "CD": cd,
        "CL": cl,
        "Cm": pitch - cx * zr / CREF + cz * xr / CREF,
        "CY": cy,
        "Cl": roll - cz * yr / BREF + cy * zr / BREF,
        "Cn": yaw - cy * xr / BREF + cx * yr / BREF,
        "alpha": al,
        "beta": be,
        "V": vt,
        "p_hat": pm * BREF / vt,
        "q_hat": qm * CREF / vt,
        "r_hat": rm * BREF / vt,
        "delta_e": data[:, 21] * D2R,
        "delta_a": 0.5 * (data[:, 28] - data[:, 27]) * D2R,
        "delta_r": data[:, 29] * D2R,
        # what a user of aeroid would start from (biases removed, SI units)
        "p": p,
        "q": q,
        "r": r,
        "p_dot": pd,
        "q_dot": qd,
        "r_dot": rd,
        "ax": ax,
        "ay": ay,
        "az": az,
        "rho": rho,
        "thrust": f_sum,
        "thrust_diff": f_diff,
        "alpha_raw": np.arctan(w / u),
        "beta_raw": np.arcsin(v / np.sqrt(u * u + v * v + w * w)),
        "V_raw": np.sqrt(u * u + v * v + w * w),
    }


def ls_stat(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The backslash estimate and LS_Stat's standard deviations ``s^2 (X'X)^-1``,
    ``s^2 = SSE / (N - p)``."""
    par = np.linalg.lstsq(x, y, rcond=None)[0]
    return par, ls_std(x, y, par)


def ls_std(x: np.ndarray, y: np.ndarray, par: np.ndarray) -> np.ndarray:
    """LS_Stat's standard deviations of the estimate `par` (any, e.g. RLS's last)."""
    n, k = x.shape
    e = y - x @ par
    return np.asarray(np.sqrt(float(e @ e) / (n - k) * np.diag(np.linalg.inv(x.T @ x))))


def rls_ff(x: np.ndarray, y: np.ndarray, lam: float, p0: Any, theta0: Any) -> np.ndarray:
    """RLSff: the estimate after every sample (gain, a priori error update, P / lambda)."""
    theta = np.array(theta0, dtype=float)
    cov = np.array(p0, dtype=float)
    out = np.empty((len(y), theta.size))
    for k, xk in enumerate(x):
        px = cov @ xk
        gain = px / (lam + xk @ px)
        theta = theta + gain * (y[k] - xk @ theta)
        cov = (cov - np.outer(gain, xk @ cov)) / lam
        out[k] = theta
    return out
