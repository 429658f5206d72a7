"""Frequency-domain identification of linear state-space models (Klein & Morelli, ch. 7).

Both methods work on the finite Fourier transforms of the measured signals
over the record ``[0, T]`` at chosen frequencies ``ω``, and need no time
integration, so they take unstable and lightly damped vehicles as they come.

* Output error: the model outputs are
  ``Y(ω) = C (jωI − A)⁻¹ [B U(ω) + c F₁(ω) + x(0) − x(T) e^{−jωT}] + D U(ω) + d F₁(ω)``
  with ``F₁(ω) = (1 − e^{−jωT})/(jω)`` the transform of a constant (so the
  affine terms ``c`` and ``d`` of the model count exactly) and ``x(0)``,
  ``x(T)`` the states at the ends of the record. The cost
  ``J = ½ Σ_ω v* S⁻¹ v``, ``v = Ỹ − Y``, is minimised by aeroid's one
  least-squares iteration (`aeroid.estimation.least_squares.minimise`) with analytic
  sensitivities, ``S = E[v v*]`` re-estimated from the residuals at every
  iteration unless given: for the likelihood weightings the cost is then
  ``M/2 log det S``, whose curvature includes the moving ``S``.
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
with ``g_ω`` the score of frequency ``ω``, each frequency's noise spectrum
estimated from its residuals divided by one minus its leverage (the
jackknife form) and its neighbours' (smoothed) — residuals at
distinct frequencies of the ``k/T`` grid are nearly independent even when
they are coloured in time, so this corrects the bound for coloured
residuals (the frequency-domain counterpart of the time-domain correction).
Frequencies off that grid (closer than ``2π/T``) share their noise through
the record's kernel; the sandwich then adds each pair's covariance
(`aeroid._colour.frequency_sandwich`).
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

from .._checks import constant_value
from .._czt import fourier
from .._records import frozen_array
from .._records import frozen_complex as _frozen_complex
from .._stats import wald_p_value
from .._threads import CALLER_STACKLEVEL, small_blas
from .._value_checks import check_choice
from ..errors import IdentifiabilityWarning, IdentificationError
from ..estimation.identifiability import unidentifiable as unidentifiable
from ..estimation.identification import IdentificationResult, names_and_initial
from ..io.data import FlightData, fingerprint, measured_start, plain, whole_number
from ..models.state_space import StateSpace
from ._frequency_domain_fits import _boundary as _boundary
from ._frequency_domain_fits import _covariances as _covariances
from ._frequency_domain_fits import _equation_error, _Fit, _output_error, _Spectra
from ._frequency_domain_fits import _stack as _stack

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


# -- argument checks -------------------------------------------------------------------------


def _frequency_grid(
    frequencies: Any, dt: float, duration: float, *, depth: int = 1, shared: bool = False
) -> FloatArray:
    """The frequencies checked; `depth`: calls between the public entry point and here;
    `shared`: the caller's error bars count the noise that close frequencies share
    (no warning about a spacing finer than ``2π/T`` then)."""
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
        if not shared and gaps.size and float(gaps.min()) < resolution * (1 - 1e-6):
            # transforms closer than 1/T share their noise: error bars that count
            # every frequency as independent come out too small
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
    max_iterations: int = 200,
    tolerance: float = 1e-8,
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
        frequency (default), or the classical Cramér–Rao bound. Output error
        with the noise covariance estimated (no `noise`) also carries the
        scatter that estimating it adds to the estimates (`aeroid._weighting`).
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
        Iteration limit of the least-squares solver (output error).
    tolerance : float
        The stopping rule of aeroid's one least-squares iteration: a step
        whose largest change of an unknown, relative to its size (at least its
        standard error at the start), is below `tolerance`, or whose decrease
        of the cost is below ``1e-3 tolerance max(|cost|, 1)``.
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
    from ..models.model import Model

    if not isinstance(model, Model):
        raise IdentificationError(
            "model: frequency-domain identification needs an aeroid.Model (state-space "
            f"dynamics), got {type(model).__name__}"
        )
    if not isinstance(data, FlightData):
        raise IdentificationError(f"data: expected FlightData, got {type(data).__name__}")
    check_choice(method, "method", _METHODS, IdentificationError)
    check_choice(boundary, "boundary", _BOUNDARY, IdentificationError)
    check_choice(weighting, "weighting", _WEIGHTING, IdentificationError)
    check_choice(error_bars, "error_bars", _ERROR_BARS, IdentificationError)
    max_iterations = whole_number(max_iterations, "max_iterations", IdentificationError)
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        tol = float("nan")
    if not tol > 0:
        raise IdentificationError(f"tolerance must be positive, got {plain(tolerance)}")
    # the same contract as time-domain identify: names, or a dict of initial guesses
    names, initial = names_and_initial(model, parameters)
    if data.n_samples < 4 or not data.is_uniform:
        raise IdentificationError(
            "data: frequency-domain identification needs a uniformly sampled record of at "
            f"least 4 samples (got {data.n_samples} samples"
            + ("" if data.is_uniform else ", non-uniform")
            + ")"
        )
    dt = float(np.mean(np.diff(data.time)))
    duration = dt * (data.n_samples - 1)
    # the frequency sandwich counts the noise close frequencies share; the white bound not
    omega = _frequency_grid(frequencies, dt, duration, shared=error_bars == "colored")
    data.require(model.controls, role="control")
    held = {c: constant_value(data[c]) for c in model.controls}
    if model.controls and all(v is not None for v in held.values()):
        listing = ", ".join(f"{c} {plain(v)}" for c, v in held.items())
        raise IdentificationError(
            f"no excitation: every control is constant ({listing}); a frequency-domain fit "
            "needs a control that varies over the record"
        )
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
        duration,
    )
    ss = StateSpace(
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
    # (a model without states has no record ends: its outputs follow the inputs at once)
    fit = run(boundary != "ignore" and bool(states), p0, tau_start)
    if boundary == "auto":
        fit = _ends_tested(fit, error_bars, len(names), len(delayed), run)
    names = names + [f"delay.{c}" for c in tau0]
    return _result(model, data, names, fit, method, error_bars, fit_names, omega, states)


def _ends_tested(fit: _Fit, error_bars: str, n_p: int, n_d: int, run: Any) -> _Fit:
    """`fit` if its record-end unknowns differ from zero jointly (Wald), else the fit without them."""
    n_pd = n_p + n_d
    b = fit.theta[n_pd:]
    if b.size == 0:
        return fit
    ends = slice(n_pd, None)
    covs = [fit.colored[ends, ends]] if error_bars == "colored" else []
    p_value = wald_p_value(b, [*covs, fit.white[ends, ends]])
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
    dof_all = fit.dof if error_bars == "colored" else np.full(len(fit.labels), fit.white_dof)
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
        full_covariance=cov_all,
        full_names=tuple(fit.labels),
        model_name=model.name,
        data_fingerprints=(fingerprint(data),),
        frequencies=omega,
        spectral_residuals=fit.residuals,
        residual_names=tuple(fit_names),
        degrees_of_freedom={
            lab: float(d) for lab, d in zip(fit.labels, dof_all, strict=True) if lab in names
        },
    )
