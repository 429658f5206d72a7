"""How many RK4 substeps per sample interval: the modes of df/dx decide.

`substeps_for` turns eigenvalues into a count; `auto_substeps` reads them at
a batch's start, `trajectory_substeps` along one member's simulated path (a
nonlinear model can stiffen where its states have grown). The compiled
programs apply the same demand (`substep_demand`) in their own array module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._batch_function import BatchFunction

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_MAX_AUTO_SUBSTEPS = 256
# Accumulated RK4 error of each mode of df/dx, relative to its amplitude, that the
# automatic substeps allow (`substeps_for`): far below any sensor's noise.
SUBSTEP_ERROR = 1e-5
# `trajectory_substeps` reads the modes at this many samples of the path.
_PREVIEW_POINTS = 32


def jacobian_eigenvalues(
    f: BatchFunction, t: float, x0: FloatArray, u0: FloatArray, p: Mapping[str, FloatArray]
) -> ComplexArray:
    """Eigenvalues of df/dx at the batch's initial points (central differences), all members
    together; members whose Jacobian is not finite are left out."""
    n, batch = x0.shape
    if n == 0:
        return np.zeros(0, dtype=np.complex128)
    scale = np.maximum(np.abs(x0), 1.0) * 1e-6  # (n, B)
    # columns: for each member b, n "+" then n "-" perturbations
    eye = np.eye(n)
    plus = x0.T[:, :, None] + eye[None] * scale.T[:, :, None]  # (B, n, n): [b, state, col]
    minus = x0.T[:, :, None] - eye[None] * scale.T[:, :, None]
    pts = np.concatenate([plus, minus], axis=2).transpose(1, 0, 2).reshape(n, batch * 2 * n)
    pp = {k: np.repeat(v, 2 * n) for k, v in p.items()}
    uu = np.repeat(u0, 2 * n, axis=1)
    with np.errstate(all="ignore"):
        vals = f(t, pts, uu, pp).reshape(n, batch, 2 * n)
        jac = (vals[:, :, :n] - vals[:, :, n:]) / (2 * scale.T[None, :, :])  # (n_out, B, n_in)
    jac = jac.transpose(1, 0, 2)
    finite = np.all(np.isfinite(jac), axis=(1, 2))
    if not np.any(finite):
        return np.zeros(0, dtype=np.complex128)
    return np.asarray(np.linalg.eigvals(jac[finite]).ravel(), dtype=np.complex128)


def substeps_for(eigenvalues: ComplexArray, h: float, duration: float) -> int:
    """RK4 substeps per sample interval `h` for modes with these eigenvalues.

    One RK4 step of ``h |λ| = z`` errs by about ``z^5 / 120`` of the mode's
    amplitude, and the errors add up while the mode lasts: about
    ``1 / (ζ z)`` steps for a mode of damping ratio ζ, at most the record
    (``|λ| T / z`` steps). Each mode gets the largest substep whose
    accumulated error stays below `SUBSTEP_ERROR` of its amplitude,
    ``z <= (120 E max(ζ, 1 / (|λ| T)))^(1/4)``: about 0.19 for a real decaying
    mode, about 0.06 for an undamped oscillation a hundred radians long.
    """
    lam = np.asarray(eigenvalues, dtype=np.complex128)
    size = np.abs(lam)
    lam, size = lam[size > 0], size[size > 0]
    if lam.size == 0 or not h > 0:
        return 1
    m = math.ceil(float(np.max(substep_demand(lam.real, size, h, duration, np))))
    return int(min(max(1, m), _MAX_AUTO_SUBSTEPS))


def substep_demand(real: Any, size: Any, h: Any, duration: Any, xp: Any) -> Any:
    """Each mode's ``h |λ| / z_max`` (`substeps_for`), from its eigenvalue's real part and
    modulus (non-zero), in the array module `xp` (numpy, or jax.numpy in a program)."""
    zeta = xp.clip(-real / size, 0.0, 1.0)
    lasting = xp.maximum(zeta, 1.0 / (size * xp.maximum(duration, h)))
    z_max = (120.0 * SUBSTEP_ERROR * lasting) ** 0.25
    return h * size / z_max


def auto_substeps(
    f: BatchFunction, time: FloatArray, x0: FloatArray, u: FloatArray, p: Mapping[str, FloatArray]
) -> int:
    lam = jacobian_eigenvalues(f, float(time[0]), x0, u[:, 0, :].T, p)
    h = float(np.max(np.diff(time)))
    return substeps_for(lam, h, float(time[-1] - time[0]))


def trajectory_substeps(
    f: BatchFunction,
    time: FloatArray,
    states: FloatArray,
    u: FloatArray,
    p: Mapping[str, FloatArray],
) -> int:
    """`substeps_for` over the modes at `_PREVIEW_POINTS` samples of one member's
    trajectory, `states` (n_t, n_x) under controls `u` (n_t, n_u) and parameters `p`
    (name -> (1,)): a nonlinear model can stiffen far from where it starts (a cubic
    damping term is no mode at all at rest). Non-finite samples are left out."""
    n_t = time.size
    picks = np.unique(np.linspace(0, n_t - 1, min(n_t, _PREVIEW_POINTS)).round().astype(int))
    picks = picks[np.all(np.isfinite(states[picks]), axis=1)]
    if picks.size == 0:
        return 1
    lam = np.concatenate(
        [
            jacobian_eigenvalues(f, float(time[k]), states[k][:, None], u[k][:, None], p)
            for k in picks
        ]
    )
    h = float(np.max(np.diff(time)))
    return substeps_for(lam, h, float(time[-1] - time[0]))
