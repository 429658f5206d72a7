"""Frequency-domain identification of linear state-space models (Klein & Morelli, ch. 7).

Both methods work on the finite Fourier transforms of the measured signals
over the record ``[0, T]`` at chosen frequencies ``ω``, and need no time
integration, so they take unstable and lightly damped vehicles as they come.

* Output error: the model outputs are
  ``Y(ω) = C (jωI − A)⁻¹ [B U(ω) + c F₁(ω) + x(0) − x(T) e^{−jωT}] + D U(ω) + d F₁(ω)``
  with ``F₁(ω) = (1 − e^{−jωT})/(jω)`` the transform of a constant (so the
  affine terms ``c`` and ``d`` of the model count exactly) and ``x(0)``,
  ``x(T)`` the states at the ends of the record. The cost
  ``J = ½ Σ_ω v* S⁻¹ v``, ``v = Ỹ − Y``, is minimised by Gauss–Newton with
  analytic sensitivities, ``S = E[v v*]`` re-estimated from the residuals
  at every iteration (relaxation) unless given.
* Equation error (Fourier transform regression): with every state measured,
  ``jω X̃ + x(T) e^{−jωT} − x(0) = A X̃ + B Ũ + c F₁`` is linear in parameters
  that enter ``A``, ``B``, ``c`` affinely, and is solved as complex least
  squares with real parameters (real and imaginary parts stacked), one
  residual variance per state equation.

The ends of the record: SIDPAC drops the ``x(0)`` and ``x(T)`` terms, which
is right when the record starts and ends at trim. Here they are estimated
(unknowns that enter linearly, two per state, or one per state on the
``ω = 2πk/T`` grid, where ``e^{−jωT} = 1`` and only the jump ``x(0) − x(T)``
shows), which removes that condition, and by default (``boundary="auto"``)
kept only when a Wald test finds them jointly different from zero: a record
at trim then gets SIDPAC's fit and pays no variance for unknowns it does not
need. ``boundary="ignore"`` is SIDPAC's choice, ``"estimate"`` always keeps
them. On that grid ``F₁ = 0`` too: trim
values and constant sensor biases have no transform and drop out (a drift
does not).

Equation error inherits the time domain's errors-in-variables bias when the
measured states are noisy, and in a band-limited fit process noise biases
it as well (``X̃(ω)`` holds the disturbance of the same frequency); output
error with measurement noise has neither problem.

The transforms: controls are piecewise linear between samples (AeroID's
simulation contract), and their transform is the exact integral of that
interpolant; states and outputs are integrated exactly as piecewise cubics
through four neighbouring samples (one-sided at the ends). Both reduce to
Euler sums (chirp-z, `aeroid._czt.fourier`) of the interpolants'
coefficients, times closed-form integrals over one interval: the endpoint and
interpolation corrections of the Euler approximation.

Error bars: the Cramér–Rao bound ``(2 Σ_ω Re(∂Y* S⁻¹ ∂Y))⁻¹`` (``"white"``,
with the ``N/(N − p)`` factor of an ``S`` estimated from ``N`` real
residuals; each complex residual is two real observations of variance
``S/2``, hence the 2 — SIDPAC's ``fdoe`` reports ``(Σ_ω Re(…))⁻¹``, so its
standard errors are √2 larger for the same fit, which our coverage tests
refute on white noise), or (default ``"colored"``) the sandwich that lets the residual
spectrum vary with frequency and between outputs, ``M⁻¹ (Σ_ω g_ω g_ωᵀ) M⁻¹``
with ``g_ω`` the score of frequency ``ω``, each frequency's residuals
divided by one minus its leverage (the jackknife form) — residuals at
distinct frequencies of the ``k/T`` grid are nearly independent even when
they are coloured in time, so this corrects the bound for coloured
residuals (the frequency-domain counterpart of the time-domain correction).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _integrate
from ._colour import frequency_sandwich
from ._czt import fourier
from ._identifiability import unidentifiable
from ._records import frozen_array
from ._records import frozen_complex as _frozen_complex
from ._threads import CALLER_STACKLEVEL, small_blas
from .data import FlightData, fingerprint, measured_start, plain, whole_number
from .errors import IdentifiabilityWarning, IdentificationError
from .identification import IdentificationResult, _names_and_initial

__all__ = ["FrequencyDomainResult", "identify_frequency_domain"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_METHODS = ("output_error", "equation_error")
_BOUNDARY = ("auto", "estimate", "ignore")
_BOUNDARY_LEVEL = 0.05  # Wald test level below which estimated record ends are kept
_ERROR_BARS = ("colored", "white")
_WEIGHTING = ("hermitian", "real", "sidpac")
_DEFAULT_BAND_HZ = (0.1, 2.0)


@dataclass(frozen=True, eq=False)
class FrequencyDomainResult(IdentificationResult):
    """An `IdentificationResult` of a frequency-domain fit, with its spectra.

    Everything that takes an identification result (`validate`, `propagate`,
    `report`, ...) takes this one. ``residuals`` is empty (no time-domain
    residuals exist); the transformed ones are in `spectral_residuals`.
    When the ends of the record were estimated, ``extra_stderr`` holds their
    standard errors: on the default ``k/T`` frequency grid only the jump
    ``x(0) − x(T)`` enters, keyed ``"jump[0].<state>"``; on other grids both
    ends, keyed ``"x0[0].<state>"`` and ``"xT[0].<state>"``, and then
    ``initial_states`` holds the estimated state at the first sample (so
    `validate` on the same record starts from it).

    Attributes
    ----------
    frequencies : ndarray, shape (m,)
        The frequencies of the fit, rad/s.
    spectral_residuals : ndarray of complex, shape (m, n)
        Transformed residuals: measured minus model outputs (output error) or
        state-equation errors (equation error, one column per state).
    residual_names : tuple of str
        The columns of `spectral_residuals`.
    """

    frequencies: FloatArray = field(default_factory=lambda: frozen_array(np.zeros(0)))
    spectral_residuals: ComplexArray = field(
        default_factory=lambda: _frozen_complex(np.zeros((0, 0)))
    )
    residual_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "frequencies", frozen_array(self.frequencies))
        object.__setattr__(self, "spectral_residuals", _frozen_complex(self.spectral_residuals))
        object.__setattr__(self, "residual_names", tuple(self.residual_names))

    def plot(self, **kwargs: Any) -> Any:
        """Residual magnitude against frequency and the estimates with 95 % error bars.

        Returns a matplotlib Figure.
        """
        import matplotlib.pyplot as plt

        names = list(self.parameter_names)
        cols = list(self.residual_names)
        fig, axes = plt.subplots(len(cols) + 1, 1, figsize=(7, 2.0 * (len(cols) + 1)), **kwargs)
        axes = np.atleast_1d(axes)
        hz = self.frequencies / (2 * np.pi)
        for k, name in enumerate(cols):
            ax = axes[k]
            ax.semilogy(hz, np.abs(self.spectral_residuals[:, k]), ".-", lw=0.8)
            ax.set_ylabel(f"|{name} residual|")
            ax.set_xlabel("frequency (Hz)")
        ax = axes[-1]
        est = np.array([self.parameters[n] for n in names])
        err = np.array([1.96 * self.stderr[n] for n in names])
        ax.errorbar(np.arange(len(names)), est, yerr=err, fmt="o", capsize=4)
        ax.set_xticks(np.arange(len(names)), names)
        ax.set_ylabel("estimate ±1.96σ")
        fig.tight_layout()
        return fig


# -- finite Fourier transform ---------------------------------------------------------------

# Inverse Vandermonde matrices of a cubic through four samples at offsets o..o+3 from
# an interval's left end (o = 0 first interval, -1 inside, -2 last): coefficients of
# s^0..s^3 on s in [0, 1].
_CUBIC = {
    o: np.linalg.inv(np.vander(np.arange(o, o + 4, dtype=np.float64), 4, increasing=True))
    for o in (0, -1, -2)
}


def _interval_integrals(theta: FloatArray, degree: int) -> ComplexArray:
    """``∫_0^1 s^m e^{−jθs} ds`` for m = 0..degree, shape (len(θ), degree + 1).

    A power series: the closed forms cancel catastrophically at small θ, and
    θ ≤ π (below Nyquist) makes 40 terms ample.
    """
    n = np.arange(40)
    fact = np.array([math.factorial(int(k)) for k in n], dtype=np.float64)
    powers = (-1j * theta[:, None]) ** n[None, :] / fact[None, :]  # (M, 40)
    m = np.arange(degree + 1)
    return np.asarray(powers @ (1.0 / (m[None, :] + n[:, None] + 1.0)), dtype=np.complex128)


def _transform(signals: FloatArray, dt: float, omega: FloatArray, *, cubic: bool) -> ComplexArray:
    """``∫_0^T x(t) e^{−jωt} dt`` of the piecewise-cubic (or -linear) interpolant, (M, k)."""
    x = np.asarray(signals, dtype=np.float64)
    n, k = x.shape
    if cubic:
        idx = np.arange(n - 1)
        start = np.clip(idx - 1, 0, n - 4)
        offset = start - idx
        windows = x[start[:, None] + np.arange(4)[None, :]]  # (n-1, 4, k)
        inv = np.stack([_CUBIC[int(o)] for o in (0, -1, -2)])[-offset]  # o -> 0, 1, 2
        coef = np.einsum("iab,ibk->iak", inv, windows)  # (n-1, 4, k)
    else:
        coef = np.stack([x[:-1], x[1:] - x[:-1]], axis=1)  # (n-1, 2, k)
    deg = coef.shape[1]
    sums = fourier(coef.reshape(n - 1, deg * k), dt, omega / (2 * np.pi))
    weights = _interval_integrals(omega * dt, deg - 1)  # (M, deg)
    return np.asarray(
        np.einsum("ma,mak->mk", weights, sums.reshape(-1, deg, k)), dtype=np.complex128
    )


# -- state-space matrices as functions of the parameters ---------------------------------------


class _StateSpace:
    """``[A B c]`` and ``[C D d]`` (selected outputs) for a batch of parameter vectors.

    A model shown linear time-invariant on the record's time grid (or declared
    so) gives them by `lti_form`; any other model is linearised by central
    differences about a reference state and control.
    """

    def __init__(
        self,
        model: Any,
        names: list[str],
        base: Mapping[str, float],
        time: FloatArray,
        rows: list[int] | None,
        reference: tuple[FloatArray, FloatArray],
    ) -> None:
        self.model = model
        self.names = names
        self.base = dict(base)
        self.n_x, self.n_u = model.n_states, model.n_controls
        self.rows = rows
        self.t0 = float(time[0])
        self.x_ref, self.u_ref = reference
        self._basis: Any = None  # None: unchecked; False: not affine; else the basis
        p1 = {k: np.array([v]) for k, v in self.base.items()}
        self.linear = True
        funs = [model._dynamics_batch]
        if rows is not None and model._measurement_batch is not None:
            funs.append(model._measurement_batch)
        for fun in funs:
            mats, not_lti = _integrate.lti_form(
                fun, time, self.n_x, self.n_u, p1, trusted=bool(model.linear)
            )
            if mats is None:
                if not not_lti:
                    raise IdentificationError(
                        f"the {fun.role} of model {model.name!r} could not be evaluated (an "
                        "exception or a non-finite value) at the initial parameters"
                    )
                self.linear = False

    def _linearised(self, fun: Any, P: Mapping[str, FloatArray]) -> FloatArray:
        batch = next(iter(P.values())).shape[0]
        n_in = self.n_x + self.n_u
        z = np.concatenate([self.x_ref, self.u_ref])
        h = 1e-6 * np.maximum(1.0, np.abs(z))
        pts = np.repeat(z[:, None], 1 + 2 * n_in, axis=1)
        pts[:, 1 : 1 + n_in] += np.diag(h)
        pts[:, 1 + n_in :] -= np.diag(h)
        Z = np.repeat(pts, batch, axis=1)  # point-major, member-minor
        PP = {k: np.tile(v, 1 + 2 * n_in) for k, v in P.items()}
        with np.errstate(all="ignore"):
            out = fun(self.t0, Z[: self.n_x], Z[self.n_x :], PP)
        vals = out.reshape(fun.n_out, 1 + 2 * n_in, batch)
        if not np.all(np.isfinite(vals)):
            raise IdentificationError(
                f"the {fun.role} of model {self.model.name!r} is not finite near the reference "
                "point of its linearisation"
            )
        jac = (vals[:, 1 : 1 + n_in] - vals[:, 1 + n_in :]) / (2 * h[None, :, None])
        M = np.empty((batch, fun.n_out, n_in + 1))
        M[:, :, :n_in] = np.transpose(jac, (2, 0, 1))
        M[:, :, n_in] = vals[:, 0, :].T - np.einsum("bij,j->bi", M[:, :, :n_in], z)
        return M

    def _form(self, fun: Any, P: Mapping[str, FloatArray]) -> FloatArray:
        if not self.linear:
            return self._linearised(fun, P)
        mats, _ = _integrate.lti_form(fun, np.array([self.t0]), self.n_x, self.n_u, P, trusted=True)
        if mats is None:
            raise IdentificationError(
                f"the {fun.role} of model {self.model.name!r} could not be evaluated (an "
                "exception or a non-finite value) at the parameters "
                f"{plain({k: v.tolist() for k, v in P.items() if k in self.names})}"
            )
        a, b, c = mats
        return np.concatenate([a, b, c[:, :, None]], axis=2)

    def matrices(self, values: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """``[A B c]`` (batch, n_x, n_x + n_u + 1) and ``[C D d]`` of the selected outputs."""
        values = np.atleast_2d(values)
        batch = values.shape[0]
        P = {k: np.full(batch, v) for k, v in self.base.items()}
        for j, n in enumerate(self.names):
            P[n] = values[:, j].copy()
        F = self._form(self.model._dynamics_batch, P)
        if self.rows is None:
            return F, None
        if self.model._measurement_batch is None:
            H = np.zeros((batch, len(self.rows), F.shape[2]))
            for i, r in enumerate(self.rows):
                H[:, i, r] = 1.0
            return F, H
        H = self._form(self.model._measurement_batch, P)[:, self.rows, :]
        return F, H

    def _central(
        self, p: FloatArray
    ) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray | None]:
        n_p = p.size
        h = 1e-4 * np.maximum(1.0, np.abs(p))
        batch = np.repeat(p[None, :], 1 + 2 * n_p, axis=0)
        batch[1 : 1 + n_p] += np.diag(h)
        batch[1 + n_p :] -= np.diag(h)
        F, H = self.matrices(batch)
        dF = (F[1 : 1 + n_p] - F[1 + n_p :]) / (2 * h[:, None, None])
        dH = None if H is None else (H[1 : 1 + n_p] - H[1 + n_p :]) / (2 * h[:, None, None])
        return F[0], None if H is None else H[0], dF, dH

    def affine(self, p0: FloatArray) -> bool:
        """Whether the matrices are affine in the parameters, checked once about `p0`.

        Then they are ``M(p) = M(p0) + Σ (p − p0)_l ∂M/∂p_l`` everywhere, and no
        model function is evaluated again.
        """
        if self._basis is None:
            F0, H0, dF, dH = self._central(p0)
            rng = np.random.default_rng(0)
            probe = p0 + np.maximum(1.0, np.abs(p0)) * rng.uniform(-0.5, 0.5, p0.size)
            Fp, Hp = self.matrices(probe)
            ok = True
            for got, at, slope in ((Fp, F0, dF), (Hp, H0, dH)):
                if got is None or at is None or slope is None:
                    continue
                want = at + np.einsum("l,lij->ij", probe - p0, slope)
                tol = 1e-7 * (np.abs(at) + np.abs(got[0]) + np.max(np.abs(at)) + 1e-300)
                ok = ok and bool(np.all(np.abs(got[0] - want) <= tol))
            self._basis = (p0.copy(), F0, H0, dF, dH) if ok else False
        return self._basis is not False

    def with_slopes(
        self, p: FloatArray
    ) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray | None]:
        """Matrices at `p` and their slopes in each parameter (central differences)."""
        if not self._basis:
            return self._central(p)
        p0, F0, H0, dF, dH = self._basis
        F = F0 + np.einsum("l,lij->ij", p - p0, dF)
        H = None if H0 is None else H0 + np.einsum("l,lij->ij", p - p0, dH)
        return F, H, dF, dH

    def at(self, p: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """Matrices at one parameter vector."""
        if self._basis:
            F, H, _, _ = self.with_slopes(p)
            return F, H
        Fb, Hb = self.matrices(p)
        return Fb[0], None if Hb is None else Hb[0]


# -- argument checks -------------------------------------------------------------------------


def _frequency_grid(frequencies: Any, dt: float, duration: float, *, depth: int = 1) -> FloatArray:
    """The frequencies checked; `depth`: calls between the public entry point and here."""
    nyquist = np.pi / dt
    if frequencies is None:
        # The k/T grid of the record: transformed white noise is then uncorrelated
        # between frequencies, which the error bars assume.
        df = 1.0 / duration
        lo, hi = _DEFAULT_BAND_HZ
        # and from two periods in the record up, the rule every window obeys
        k = np.arange(max(math.ceil(lo / df - 1e-9), 2), math.floor(hi / df + 1e-9) + 1)
        omega = 2 * np.pi * df * k.astype(np.float64)
    else:
        try:
            omega = np.atleast_1d(np.asarray(frequencies, dtype=np.float64))
        except (TypeError, ValueError):
            raise IdentificationError(
                f"frequencies: expected an array of frequencies in rad/s, got {plain(frequencies)}"
            ) from None
        if omega.ndim != 1 or not np.all(np.isfinite(omega)):
            raise IdentificationError(
                "frequencies: expected a 1-D array of finite frequencies in rad/s"
            )
        if np.any(omega < 0):
            raise IdentificationError(
                f"frequencies: negative value {float(omega[omega < 0][0]):.6g} rad/s; give "
                "frequencies in rad/s, above zero"
            )
        omega = omega[omega > 0]  # the zero frequency carries only the mean: dropped
        if np.unique(omega).size != omega.size:
            raise IdentificationError("frequencies: a frequency is listed twice")
        gaps = np.diff(np.sort(omega))
        resolution = 2 * np.pi / duration
        if gaps.size and float(gaps.min()) < resolution * (1 - 1e-6):
            # transforms closer than 1/T share their noise: the error bars, which count
            # every frequency as independent, come out too small
            warnings.warn(
                f"frequencies: spacing {float(gaps.min()):.4g} rad/s is finer than the "
                f"record's resolution 2π/T = {resolution:.4g} rad/s; neighbouring transforms "
                "then share their noise and the error bars are too small",
                UserWarning,
                stacklevel=CALLER_STACKLEVEL + depth,
            )
    if omega.size and float(omega.max()) >= nyquist:
        raise IdentificationError(
            f"frequencies: {float(omega.max()):.6g} rad/s is at or above the Nyquist frequency "
            f"{nyquist:.6g} rad/s of the record ({1 / dt:.6g} Hz sampling)"
        )
    return omega


def _reference(model: Any, data: FlightData, reference: Any) -> tuple[FloatArray, FloatArray]:
    """The linearisation point: given values, else the first measured sample (zero if not)."""
    x = measured_start(data, model.states)
    u = {c: float(data[c][0]) for c in model.controls}
    if reference is not None:
        if not isinstance(reference, Mapping):
            raise IdentificationError(
                f"reference: expected a mapping of state/control name -> value, got "
                f"{plain(reference)}"
            )
        for k, v in reference.items():
            if k not in model.states and k not in model.controls:
                raise IdentificationError(
                    f"reference: {k!r} is neither a state nor a control of model {model.name!r}"
                )
            try:
                val = float(v)
            except (TypeError, ValueError):
                raise IdentificationError(
                    f"reference[{k!r}]: expected a number, got {plain(v)}"
                ) from None
            (x if k in model.states else u)[k] = val
    return (
        np.array([x.get(s, 0.0) for s in model.states]),
        np.array([u[c] for c in model.controls]),
    )


# -- shared statistics ---------------------------------------------------------------------


def _covariances(
    jac: FloatArray, res: FloatArray, labels: list[str], white_scale: float
) -> tuple[FloatArray, FloatArray, list[tuple[str, ...]], Any]:
    """White and frequency-sandwich covariances of a weighted real least squares.

    `jac` (M, r, n) and `res` (M, r): per frequency, the real-stacked weighted
    sensitivities and residuals. The white covariance is `white_scale` times
    the inverse information (the variance of one weighted real row); the
    sandwich takes the scale from the residuals themselves, with the
    ``N/(N − n)`` factor of the unknowns they absorbed.
    """
    m, r, n = jac.shape
    J = jac.reshape(m * r, n)
    info = J.T @ J
    combos, null = unidentifiable(info, labels)
    inv = np.linalg.pinv(info, rcond=1e-13, hermitian=True)
    white = white_scale * inv
    # the one coloured-residual correction, in its per-frequency form: the few
    # frequencies near a mode carry most of the information, and the fit pulls
    # their residuals towards zero (their leverage)
    colored = frequency_sandwich(jac, res, np.asarray(inv, dtype=np.float64))
    for cov in (white, colored):
        for j in np.flatnonzero(null):
            cov[j, :] = np.nan
            cov[:, j] = np.nan
            cov[j, j] = np.inf
    return (
        np.asarray(white, dtype=np.float64),
        np.asarray(colored, dtype=np.float64),
        combos,
        null,
    )


def _stack(z: ComplexArray) -> FloatArray:
    """(M, r, ...) complex -> (M, 2r, ...) real: real parts, then imaginary parts."""
    return np.concatenate([z.real, z.imag], axis=1)


# -- the two methods -----------------------------------------------------------------------


@dataclass
class _Spectra:
    omega: FloatArray
    U: ComplexArray  # (M, n_u + 1): controls and the constant's transform F1
    end: ComplexArray  # (M,) e^{-jωT}
    Z: ComplexArray  # (M, n_z): measured outputs (output error) or states (equation error)
    span: float  # Δt T: noise power of a unit-variance white sequence's transform


@dataclass
class _Fit:
    theta: FloatArray
    labels: list[str]
    white: FloatArray
    colored: FloatArray
    combos: list[tuple[str, ...]]
    cost: float
    noise: FloatArray
    residuals: ComplexArray
    iterations: int
    success: bool
    message: str


def _boundary(sp: _Spectra, states: list[str]) -> tuple[ComplexArray, list[str]]:
    """Forcing of the state equations per unit end state, (M, k, n_x), and its labels.

    ``x(0) − x(T) e^{−jωT}``: on the ``k/T`` grid ``e^{−jωT} = 1`` and only the
    jump ``x(0) − x(T)`` shows, one unknown per state; elsewhere both ends.
    """
    n_x = len(states)
    eye = np.broadcast_to(np.eye(n_x), (sp.omega.size, n_x, n_x)).astype(np.complex128)
    if np.max(np.abs(1.0 - sp.end)) < 1e-9:
        return eye, [f"jump[0].{s}" for s in states]
    last = -sp.end[:, None, None] * np.eye(n_x)
    labels = [f"x0[0].{s}" for s in states] + [f"xT[0].{s}" for s in states]
    return np.concatenate([eye, last], axis=1), labels


def _equation_error(
    ss: _StateSpace, sp: _Spectra, p0: FloatArray, boundary: bool, states: list[str]
) -> _Fit:
    n_x, n_p = ss.n_x, p0.size
    if not ss.affine(p0):
        raise IdentificationError(
            "method='equation_error' needs state equations whose matrices A, B (and constant "
            "c) are affine in the estimated parameters; use method='output_error'"
        )
    F0, _, dF, _ = ss.with_slopes(p0)
    Xa = np.concatenate([sp.Z, sp.U], axis=1)  # (M, n_x + n_u + 1)
    lhs = 1j * sp.omega[:, None] * sp.Z - Xa @ F0.T  # (M, n_x)
    cols = np.einsum("lia,ma->mil", dF, Xa)  # (M, n_x, n_p)
    labels = list(ss.names)
    if boundary:
        bcols, blabels = _boundary(sp, states)
        cols = np.concatenate([cols, bcols.transpose(0, 2, 1)], axis=2)
        labels += blabels
    present = np.any(np.abs(cols) > 0, axis=0)  # (n_x, n_unknown)
    absent = np.flatnonzero(~present[:, :n_p].any(axis=0))
    if absent.size:
        raise IdentificationError(
            f"parameters {[ss.names[j] for j in absent]} do not enter the state equations "
            "at these frequencies; equation error cannot estimate them (use "
            "method='output_error' for parameters of the outputs)"
        )
    m = sp.omega.size
    k_i = present.sum(axis=1)
    if np.any(2 * m <= k_i):
        raise IdentificationError(
            f"too few frequencies: {m} frequencies (2 real equations each) cannot estimate "
            f"{int(k_i.max())} unknowns of one state equation"
        )
    weight = np.ones(n_x)
    theta = np.zeros(cols.shape[2])
    for _ in range(3):  # equal weights, then each equation's residual variance (twice)
        A = _stack(cols * weight[None, :, None])
        b = _stack(lhs * weight[None, :])
        theta = np.linalg.lstsq(A.reshape(-1, A.shape[2]), b.reshape(-1), rcond=None)[0]
        v = lhs - cols @ theta
        var = np.sum(np.abs(v) ** 2, axis=0) / (2 * m - k_i)  # per real component
        # an exact fit (noise-free data) must not give infinite weights
        floor = 1e-24 * np.mean(np.abs(lhs) ** 2, axis=0) + 1e-300
        weight = 1.0 / np.sqrt(np.maximum(var, floor))
    jac = _stack(cols * weight[None, :, None])
    res = _stack(v * weight[None, :])
    # each weighted real row has unit variance (its variance already counts the unknowns)
    white, colored, combos, _ = _covariances(jac, res, labels, 1.0)
    theta[:n_p] += p0
    return _Fit(
        theta,
        labels,
        white,
        colored,
        combos,
        0.25 * float(np.sum(np.abs(v * weight[None, :]) ** 2)),  # ½ Σ v* S⁻¹ v, S = 2 var
        np.diag(2.0 * var / sp.span),
        v,
        1,
        True,
        "closed-form least squares",
    )


def _output_error(
    ss: _StateSpace,
    sp: _Spectra,
    p0: FloatArray,
    boundary: bool,
    states: list[str],
    noise: FloatArray | None,
    max_iterations: int,
    tolerance: float,
    cross: str = "hermitian",
    delayed: Sequence[int] = (),
    tau0: FloatArray | None = None,
) -> _Fit:
    n_x, n_p = ss.n_x, p0.size
    n_d = len(delayed)
    labels = list(ss.names) + [f"delay[{j}]" for j in delayed]
    bcols: ComplexArray | None = None
    if boundary:
        bcols, blabels = _boundary(sp, states)
        labels += blabels
    n_b = len(labels) - n_p - n_d
    n_pd = n_p + n_d
    dcols = list(delayed)
    jwU = -1j * sp.omega[:, None]
    jw = 1j * sp.omega[:, None, None] * np.eye(n_x)
    bT = None if bcols is None else np.ascontiguousarray(bcols.transpose(0, 2, 1))

    def evaluate(theta: FloatArray, slopes: bool) -> tuple[ComplexArray, ComplexArray | None]:
        p = theta[:n_p]
        U = sp.U
        if n_d:
            # a pure input delay τ: U(ω) e^{−jωτ}
            U = U.copy()
            U[:, dcols] = U[:, dcols] * np.exp(jwU * theta[n_p:n_pd][None, :])
        if slopes:
            F, H, dF, dH = ss.with_slopes(p)
        else:
            F, H = ss.at(p)
            dF, dH = None, None
        assert H is not None
        A = F[:, :n_x]
        forcing = U @ F[:, n_x:].T  # (M, n_x)
        if bT is not None:
            forcing = forcing + bT @ theta[n_pd:]
        with np.errstate(all="ignore"):
            G = np.linalg.inv(jw - A)
        X = (G @ forcing[:, :, None])[:, :, 0]
        Xa = np.concatenate([X, U], axis=1)
        v = sp.Z - Xa @ H.T
        if not slopes:
            return v, None
        assert dF is not None and dH is not None
        n_a, n_y = Xa.shape[1], H.shape[0]
        CG = H[:, :n_x] @ G  # (M, n_y, n_x)
        # ∂Y/∂p_l = C G (∂F_l Xa) + ∂H_l Xa, as plain matrix products
        dFXa = (Xa @ dF.reshape(n_p * n_x, n_a).T).reshape(-1, n_p, n_x).transpose(0, 2, 1)
        dHXa = (Xa @ dH.reshape(n_p * n_y, n_a).T).reshape(-1, n_p, n_y).transpose(0, 2, 1)
        dY = CG @ dFXa + dHXa
        if n_d:
            # ∂U_j/∂τ_j = −jω U_j: through the state equations and the feedthrough
            dU = jwU * U[:, dcols]  # (M, n_d)
            bd = F[:, n_x:][:, dcols]  # (n_x, n_d)
            dd = H[:, n_x:][:, dcols]  # (n_y, n_d)
            dYd = CG @ (bd[None, :, :] * dU[:, None, :]) + dd[None, :, :] * dU[:, None, :]
            dY = np.concatenate([dY, dYd], axis=2)
        if bT is not None:
            dY = np.concatenate([dY, CG @ bT], axis=2)
        return v, np.asarray(dY, dtype=np.complex128)

    def weighting(v: ComplexArray) -> ComplexArray:
        # the full Hermitian covariance: outputs whose noise is correlated with a phase
        # shift (one sensor lagging another) have a complex cross term that the real
        # part alone throws away
        if noise is not None:
            S = (noise * sp.span).astype(np.complex128)
        else:
            S = v.T @ v.conj() / v.shape[0]
            if cross == "real":
                S = S.real.astype(np.complex128)
            elif cross == "sidpac":
                S = S.conj()  # fdoe's E[v̄ vᵀ]: the transpose of the covariance
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise IdentificationError(
                "output error: the residual covariance is singular (an output the model fits "
                "exactly, or two identical outputs); drop that output or give noise="
            ) from None
        return np.asarray(np.linalg.inv(L), dtype=np.complex128)

    def cost_of(v: ComplexArray, Li: ComplexArray) -> float:
        e = v @ Li.T
        return 0.5 * float(np.sum(e.real**2 + e.imag**2))

    ss.affine(p0)  # then the iterations evaluate no model function
    tau = np.zeros(n_d) if tau0 is None else np.asarray(tau0, dtype=np.float64)
    theta = np.concatenate([p0, tau, np.zeros(n_b)])
    v, dY = evaluate(theta, True)
    if not np.all(np.isfinite(v)):
        raise IdentificationError(
            "output error: the model outputs are not finite at the initial parameters (a pole "
            "on a chosen frequency?)"
        )
    success, message, it = False, f"iteration limit {max_iterations} reached", 0
    Li = weighting(v)
    if boundary and noise is None:
        # the ends enter linearly: solve for them first, so the first noise estimate
        # is not swamped by the transients they leave
        assert dY is not None
        Jb = _stack(Li @ dY[:, :, n_pd:])
        rb = _stack(v @ Li.T)
        theta[n_pd:] = np.linalg.lstsq(Jb.reshape(-1, n_b), rb.reshape(-1), rcond=None)[0]
        v, dY = evaluate(theta, True)
        Li = weighting(v)

    def objective(v: ComplexArray) -> float:
        # the negative log-likelihood less constants: with the noise covariance
        # estimated it is concentrated out, leaving log det S (the weighted sum of
        # squares is then n_y M / 2 whatever the parameters)
        if not np.all(np.isfinite(v)):
            return np.inf
        if noise is not None or cross == "sidpac":
            # (fdoe's weighting is no likelihood's: its fixed point is searched with
            # the weighting held, as fdoe does)
            return cost_of(v, Li)
        S = v.T @ v.conj() / v.shape[0]
        sign, logdet = np.linalg.slogdet(S.real if cross == "real" else S)
        return float(logdet) if sign.real > 0 else np.inf

    before = [theta.copy(), theta.copy()]  # the last two iterates
    for step in range(1, max_iterations + 1):
        it = step
        assert dY is not None
        Li = weighting(v)
        J = _stack(Li @ dY).reshape(-1, theta.size)
        r = _stack(v @ Li.T).reshape(-1)
        norms = np.linalg.norm(J, axis=0)
        norms[norms == 0] = 1.0
        Jn = J / norms
        delta = np.linalg.lstsq(Jn, r, rcond=None)[0] / norms
        # standard errors at this weighting (a weighted real row has variance 1/2)
        se = np.sqrt(0.5 * np.abs(np.diag(np.linalg.pinv(Jn.T @ Jn, hermitian=True)))) / norms
        f0 = objective(v)
        alpha, best, f_best = 1.0, None, f0
        for _ in range(20):
            f_t = objective(evaluate(theta + alpha * delta, False)[0])
            if f_t <= f_best + 1e-12 * abs(f_best):
                best, f_best = alpha, f_t
                break
            alpha *= 0.5
        if best == 1.0 and noise is None and cross != "sidpac":
            # re-estimating the noise between steps converges only linearly, each
            # step short of the optimum along nearly the same line: go further
            # while the likelihood still rises
            for _ in range(6):
                f_t = objective(evaluate(theta + 2.0 * best * delta, False)[0])
                if not f_t < f_best:
                    break
                best, f_best = 2.0 * best, f_t
        if best is None:
            # no decrease along the Gauss-Newton step: at the minimum to rounding when
            # that step is tiny against the error bars, stuck otherwise
            if np.all(np.abs(delta) <= 1e-3 * se + 1e-12 * np.abs(theta)):
                success, message = True, "converged (no further decrease of the cost)"
            else:
                message = "the line search found no decrease of the cost"
            break
        theta = theta + best * delta
        v, dY = evaluate(theta, True)
        # converged once no parameter moves by more than `tolerance` of its error bar
        small = tolerance * se + 1e-12 * np.abs(theta)
        if np.all(np.abs(best * delta) <= small):
            success, message = True, "converged"
            break
        if step > 2 and np.all(np.abs(theta - before[0]) <= small):
            # re-estimating the noise can settle into a two-step cycle about the fixed
            # point (fdoe's weighting is no likelihood that would forbid it)
            success, message = True, "converged (the noise re-estimate cycles within tolerance)"
            break
        before = [before[1], theta.copy()]
    if not success:
        warnings.warn(
            f"identify_frequency_domain: {message}; the result is flagged success=False",
            UserWarning,
            stacklevel=CALLER_STACKLEVEL + 1,
        )
    assert dY is not None
    Li = weighting(v)
    jac = _stack(Li @ dY)
    res = _stack(v @ Li.T)
    # a weighted real row has variance ½ (circular complex noise), and an estimated S
    # is short by the unknowns the fit absorbed
    n_rows = res.size
    scale = 0.5 if noise is not None else 0.5 * n_rows / max(n_rows - theta.size, 1)
    white, colored, combos, _ = _covariances(jac, res, labels, scale)
    S = np.linalg.inv(Li.conj().T @ Li)
    return _Fit(
        theta,
        labels,
        white,
        colored,
        combos,
        cost_of(v, Li),
        np.asarray((S / sp.span).real, dtype=np.float64),
        v,
        it,
        success,
        message,
    )


# -- public entry point ---------------------------------------------------------------------


@small_blas
def identify_frequency_domain(
    model: Any,
    data: FlightData,
    parameters: Sequence[str] | Mapping[str, float],
    *,
    frequencies: ArrayLike | None = None,
    method: str = "output_error",
    outputs: Sequence[str] | None = None,
    boundary: str = "auto",
    error_bars: str = "colored",
    noise: Mapping[str, float] | None = None,
    reference: Mapping[str, float] | None = None,
    max_iterations: int = 100,
    tolerance: float = 1e-4,
    weighting: str = "sidpac",
    delays: Sequence[str] | Mapping[str, float] | None = None,
) -> FrequencyDomainResult:
    """Estimate the parameters of a linear(ised) state-space model in the frequency domain.

    Parameters
    ----------
    model : Model
        Linear time-invariant in states and controls (shown on the record's
        time grid, or declared with ``linear=True``); any other model is
        linearised about `reference`. Its matrices may depend on the
        parameters in any smooth way for output error, affinely for equation
        error.
    data : FlightData
        One uniformly sampled record with the model's controls and the fitted
        outputs (output error) or every state (equation error).
    parameters : sequence of str or mapping of str to float
        Names to estimate (from their nominal values) or name -> initial
        guess; the other parameters stay at their nominal values.
    frequencies : array_like, optional
        Frequencies in rad/s, above zero and below Nyquist (a zero entry is
        dropped: it carries only the mean). Default: the multiples of ``1/T``
        (``T`` the record length) from 0.1 Hz, or ``2/T`` (two periods in the
        record) if higher, to 2 Hz, on which the transformed
        noise of distinct frequencies is uncorrelated, as the error bars
        assume; a finer grid gives error bars that are too small.
    method : {"output_error", "equation_error"}
        Frequency-domain output error, or Fourier transform regression (needs
        every state measured; noisy states bias it, as in the time domain).
    outputs : sequence of str, optional
        Output error: the outputs to fit (default every model output present
        in the data).
    boundary : {"auto", "estimate", "ignore"}
        Estimate the states at the ends of the record (they enter linearly),
        or drop their terms as SIDPAC does, which is right when the record
        starts and ends at trim. ``"auto"`` (default) estimates them and
        keeps them only when they differ from zero jointly (a Wald test at
        the 5 % level with the reported covariance): ends at trim then cost
        no variance, ends away from trim no bias. The result's `message`
        says which was kept.
    error_bars : {"colored", "white"}
        The frequency sandwich that lets the residual spectrum vary with
        frequency (default), or the classical Cramér–Rao bound.
    noise : mapping of str to float, optional
        Output error: standard deviations of white measurement noise per
        fitted output; the noise covariance of the transforms is then fixed
        instead of estimated from the residuals.
    reference : mapping of str to float, optional
        States and controls of the linearisation point of a model that is
        not linear time-invariant (default: the first sample of the measured
        ones, zero for the others); the record should hold perturbations
        small about it.
    max_iterations : int
        Gauss–Newton iteration limit (output error).
    tolerance : float
        Convergence threshold: no parameter moves by more than `tolerance`
        times its standard error in the last step.
    weighting : {"sidpac", "hermitian", "real"}
        Output error with an estimated noise covariance. ``"sidpac"``
        (default): ``Σ v̄ vᵀ``, what SIDPAC's ``fdoe`` forms (its ``v'*v`` on
        the frequency-by-output residual array), so that the estimates
        reproduce fdoe's and the published Klein & Morelli examples (Example
        7.1 within 0.18 of its standard errors); it is the conjugate of the
        covariance ``S = (1/M) Σ v vᴴ``. ``"hermitian"``: ``S`` itself, the
        maximum-likelihood weighting of circular complex residuals (the fit
        then minimises ``log det S``); when the residual cross-spectra are
        complex (one output a quarter turn from another, as roll angle from
        roll rate, under process noise) it gives the smaller errors, and
        results that differ from fdoe's (Example 7.1: up to 6 of fdoe's
        standard errors). ``"real"``: the real part of ``S`` (the weighting
        before 0.2). All three agree when the cross-spectra are real.
    delays : sequence of str or mapping of str to float, optional
        Output error: controls whose pure time delay ``τ`` (``U(ω) e^{−jωτ}``,
        seconds) is estimated with the parameters (from 0, or the given
        initial guess); reported as parameters ``"delay.<control>"``.

    Returns
    -------
    FrequencyDomainResult
        An `IdentificationResult` (``method`` ``"frequency_domain_output_error"``
        or ``"frequency_domain_equation_error"``) with the spectra of the fit.

    Raises
    ------
    IdentificationError
        A parameter the model lacks, a frequency at or above Nyquist or below
        zero, too few frequencies for the unknowns, non-uniform sampling, a
        model whose equation-error form is not linear in the parameters, or
        bad options.
    ChannelError
        A control, output or (equation error) state missing from the data.

    Warns
    -----
    IdentifiabilityWarning
        When the data cannot separate some parameters (their error bars are
        infinite and the result is flagged).
    UserWarning
        When output error reaches the iteration limit (flagged ``success=False``).
    """
    from .model import Model

    if not isinstance(model, Model):
        raise IdentificationError(
            "model: frequency-domain identification needs an aeroid.Model (state-space "
            f"dynamics), got {type(model).__name__}"
        )
    if not isinstance(data, FlightData):
        raise IdentificationError(f"data: expected FlightData, got {type(data).__name__}")
    if method not in _METHODS:
        raise IdentificationError(f"method {method!r} is unknown; choose one of {list(_METHODS)}")
    if boundary not in _BOUNDARY:
        raise IdentificationError(
            f"boundary {boundary!r} is unknown; choose one of {list(_BOUNDARY)}"
        )
    if weighting not in _WEIGHTING:
        raise IdentificationError(
            f"weighting {weighting!r} is unknown; choose one of {list(_WEIGHTING)}"
        )
    if error_bars not in _ERROR_BARS:
        raise IdentificationError(
            f"error_bars {error_bars!r} is unknown; choose one of {list(_ERROR_BARS)}"
        )
    max_iterations = whole_number(max_iterations, "max_iterations", IdentificationError)
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        tol = float("nan")
    if not tol > 0:
        raise IdentificationError(f"tolerance must be positive, got {plain(tolerance)}")
    # the same contract as time-domain identify: names, or a dict of initial guesses
    names, initial = _names_and_initial(model, parameters)
    if data.n_samples < 4 or not data.is_uniform:
        raise IdentificationError(
            "data: frequency-domain identification needs a uniformly sampled record of at "
            f"least 4 samples (got {data.n_samples} samples"
            + ("" if data.is_uniform else ", non-uniform")
            + ")"
        )
    dt = float(np.mean(np.diff(data.time)))
    duration = dt * (data.n_samples - 1)
    omega = _frequency_grid(frequencies, dt, duration)
    data.require(model.controls, role="control")
    states = list(model.states)
    if method == "equation_error":
        if outputs is not None or noise is not None:
            raise IdentificationError(
                "outputs and noise apply to method='output_error' only; equation error fits "
                "the state equations"
            )
        data.require(states, role="state")
        fit_names = states
        rows: list[int] | None = None
    else:
        model_outputs = list(model.output_names)
        if outputs is None:
            fit_names = [o for o in model_outputs if o in data]
            if not fit_names:
                data.require(model_outputs[:1], role="output")
        else:
            chosen = [outputs] if isinstance(outputs, str) else list(outputs)
            for o in chosen:
                if o not in model_outputs:
                    raise IdentificationError(
                        f"outputs: {o!r} is not an output of model {model.name!r}; its outputs "
                        f"are {model_outputs}"
                    )
            if not chosen:
                raise IdentificationError("outputs: name at least one output to fit")
            fit_names = chosen
        data.require(fit_names, role="output")
        rows = [model_outputs.index(o) for o in fit_names]
    noise_var: FloatArray | None = None
    if noise is not None:
        if not isinstance(noise, Mapping) or set(noise) != set(fit_names):
            raise IdentificationError(
                f"noise: expected a mapping of every fitted output {fit_names} -> standard "
                f"deviation, got {plain(noise)}"
            )
        sd = np.array([float(noise[o]) for o in fit_names])
        if not np.all(np.isfinite(sd) & (sd > 0)):
            raise IdentificationError("noise: every standard deviation must be positive")
        noise_var = np.diag(sd**2)
    controls = list(model.controls)
    tau0: dict[str, float] = {}
    if delays is not None:
        if method == "equation_error":
            raise IdentificationError(
                "delays apply to method='output_error' only (equation error needs the "
                "transforms of the delayed controls as regressors)"
            )
        if isinstance(delays, str):
            delays = [delays]
        tau0 = (
            {str(k): float(v) for k, v in delays.items()}
            if isinstance(delays, Mapping)
            else dict.fromkeys(map(str, delays), 0.0)
        )
        for c, v in tau0.items():
            if c not in controls:
                raise IdentificationError(
                    f"delays: {c!r} is not a control of model {model.name!r}; its controls "
                    f"are {controls}"
                )
            if not math.isfinite(v):
                raise IdentificationError(f"delays: the initial delay of {c!r} is not finite")
    delayed = [controls.index(c) for c in tau0]
    n_unknown = len(names) + len(delayed) + (model.n_states if boundary != "ignore" else 0)
    n_real = 2 * omega.size * len(fit_names)
    if n_real <= n_unknown:
        raise IdentificationError(
            f"frequencies: too few: {omega.size} frequencies x {len(fit_names)} "
            f"{'equations' if method == 'equation_error' else 'outputs'} give {n_real} real "
            f"values for {n_unknown} unknowns; give more frequencies (a wider band or a "
            "longer record)"
        )
    U = _transform(
        data.array(list(model.controls)).reshape(data.n_samples, -1), dt, omega, cubic=False
    )
    end = np.exp(-1j * omega * duration)
    F1 = (1.0 - end) / (1j * omega)
    spectra = _Spectra(
        omega,
        np.concatenate([U, F1[:, None]], axis=1),
        end,
        _transform(data.array(fit_names), dt, omega, cubic=True),
        dt * duration,
    )
    ss = _StateSpace(
        model,
        names,
        {**dict(model.parameters), **initial},
        np.asarray(data.time),
        rows,
        _reference(model, data, reference),
    )
    p0 = np.array([initial[n] for n in names])

    def run(ends: bool, start: FloatArray, tau: FloatArray) -> _Fit:
        if method == "equation_error":
            return _equation_error(ss, spectra, start, ends, states)
        return _output_error(
            ss, spectra, start, ends, states, noise_var, max_iterations, tol, weighting,
            delayed, tau,
        )  # fmt: skip

    tau_start = np.array(list(tau0.values()))
    fit = run(boundary != "ignore", p0, tau_start)
    if boundary == "auto":
        fit = _ends_tested(fit, error_bars, len(names), len(delayed), run)
    names = names + [f"delay.{c}" for c in tau0]
    return _result(model, data, names, fit, method, error_bars, fit_names, omega, states)


def _ends_tested(fit: _Fit, error_bars: str, n_p: int, n_d: int, run: Any) -> _Fit:
    """`fit` if its record-end unknowns differ from zero jointly (Wald), else the fit without them."""
    import scipy.stats

    n_pd = n_p + n_d
    b = fit.theta[n_pd:]
    if b.size == 0:
        return fit
    cov = (fit.colored if error_bars == "colored" else fit.white)[n_pd:, n_pd:]
    try:
        wald = float(b @ np.linalg.solve(cov, b))
    except np.linalg.LinAlgError:
        wald = np.inf
    p_value = float(scipy.stats.chi2.sf(wald, b.size)) if np.isfinite(wald) else 0.0
    if p_value < _BOUNDARY_LEVEL:
        note = f"record ends estimated (Wald p = {p_value:.2g})"
        return dataclasses.replace(fit, message=f"{fit.message}; {note}")
    refit = run(False, fit.theta[:n_p], fit.theta[n_p:n_pd])
    note = f"record ends dropped: not different from zero (Wald p = {p_value:.2g})"
    return dataclasses.replace(refit, message=f"{refit.message}; {note}")


def _result(
    model: Any,
    data: FlightData,
    names: list[str],
    fit: _Fit,
    method: str,
    error_bars: str,
    fit_names: list[str],
    omega: FloatArray,
    states: list[str],
) -> FrequencyDomainResult:
    n_p = len(names)
    cov_all = fit.colored if error_bars == "colored" else fit.white
    sd_all = np.sqrt(np.clip(np.diag(cov_all), 0.0, None))
    if fit.combos:
        text = "; ".join(" + ".join(c) for c in fit.combos)
        warnings.warn(
            f"the data cannot separate these parameter combinations: {text}; their "
            "standard errors are reported as infinite",
            IdentifiabilityWarning,
            stacklevel=CALLER_STACKLEVEL + 1,
        )
    extra = {lab: float(s) for lab, s in zip(fit.labels[n_p:], sd_all[n_p:], strict=True)}
    x0 = (
        ({s: float(fit.theta[n_p + i]) for i, s in enumerate(states)},)
        if len(fit.labels) == n_p + 2 * len(states)
        else ()
    )
    return FrequencyDomainResult(
        parameters={n: float(v) for n, v in zip(names, fit.theta[:n_p], strict=True)},
        stderr={n: float(s) for n, s in zip(names, sd_all[:n_p], strict=True)},
        covariance=cov_all[:n_p, :n_p],
        parameter_names=tuple(names),
        fixed={k: float(v) for k, v in model.parameters.items() if k not in names},
        covariance_white=fit.white[:n_p, :n_p],
        error_bars=error_bars,
        identifiable=not fit.combos,
        unidentifiable=tuple(fit.combos),
        success=fit.success,
        message=fit.message,
        n_iterations=fit.iterations,
        cost=fit.cost,
        method=f"frequency_domain_{method}",
        output_names=tuple(fit_names),
        noise_covariance=fit.noise,
        initial_states=x0,
        extra_stderr=extra,
        model_name=model.name,
        data_fingerprints=(fingerprint(data),),
        frequencies=omega,
        spectral_residuals=fit.residuals,
        residual_names=tuple(fit_names),
    )
