"""The `CompatibilityResult` record, apart from `aeroid.estimation.compatibility` (which
re-exports it) so that the analysis and its record each stay one readable module."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table
from ..errors import ChannelError
from ..io.data import FlightData
from ._compat_model import _WIND
from .identification import IdentificationResult

FloatArray = NDArray[np.float64]

_UNITS = {
    "p": "rad/s",
    "q": "rad/s",
    "r": "rad/s",
    "ax": "m/s^2",
    "ay": "m/s^2",
    "az": "m/s^2",
    "V": "m/s",
    "alpha": "rad",
    "beta": "rad",
    "phi": "rad",
    "theta": "rad",
    "psi": "rad",
    "h": "m",
    "vn": "m/s",
    "ve": "m/s",
}


# -- the result ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CompatibilityResult(IntervalMixin):
    """Sensor errors, corrected data and the reconstructed flight path.

    Attributes
    ----------
    corrected : FlightData
        The input record with the estimated (and given) sensor errors
        removed, under the user's channel names: rates and specific forces
        ``(x_m - b_x) / (1 + k_x)``, outputs ``(y_m(t + tau_y) - b_y) / (1 + k_y)``
        (shifted band-limited on a uniform grid, else linearly interpolated).
        Other channels are passed through.
    parameters : mapping of str to float
        The estimated sensor parameters (see `SENSOR_PARAMETERS`).
    stderr : mapping of str to float
        Their standard errors: those of the output-error fit (see
        `error_bars`) with the share of the input noise added (see
        `check_compatibility`, Notes).
    covariance : ndarray, shape (n_p, n_p)
        Covariance of the estimates, in `parameter_names` order (the same two
        parts).
    parameter_names : tuple of str
    fixed : mapping of str to float
        Every other sensor parameter, at its given value (zero unless given).
    initial_states : mapping of str to float
        Estimated initial state: body-axis ground velocity ``u, v, w`` (m/s),
        ``phi, theta, psi`` (rad) and ``h`` (m).
    initial_state_stderr : mapping of str to float
        Standard errors of the estimated initial states.
    time : ndarray, shape (n_t,)
    output_names : tuple of str
        The fitted outputs (names of `OUTPUT_CHANNELS`).
    channels : mapping of str to str
        Data channel used for each input and fitted output.
    measured : ndarray, shape (n_t, n_y)
        The fitted outputs as recorded.
    reconstructed : ndarray, shape (n_t, n_y)
        What the sensors should have read: the kinematic reconstruction with
        the estimated scale factors, offsets and time shifts applied.
    states : ndarray, shape (n_t, 7)
        The reconstructed kinematic states `state_names`.
    true_outputs : ndarray, shape (n_t, 9)
        The reconstructed airspeed, angles and altitude free of sensor errors,
        every one of `OUTPUT_CHANNELS` (also those not measured).
    state_names : tuple of str
    error_bars : str
        ``"colored"`` or ``"white"``, as in `IdentificationResult`.
    identifiable : bool
    unidentifiable : tuple of tuple of str
        Parameter combinations the data cannot separate.
    success : bool
    message : str
    n_passes : int
        Output-error fits run (more than one when time shifts are estimated).
    gravity : float
    input_noise : mapping of str to float
        Noise standard deviation of each input used for the error bars.
    measured_states : tuple of str
        States replaced by their measurement (see `check_compatibility`).
    scale_pivots : mapping of str to float
        Per fitted output, the value its scale factor pivots about: zero, or
        the reconstructed start value (``scale_about="initial"``).
    degrees_of_freedom : mapping of str to float
        Per estimate, the degrees of freedom of its standard error (see
        `aeroid.IdentificationResult`): `interval` and `margin` take
        Student's t with it.
    """

    corrected: FlightData
    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    parameter_names: tuple[str, ...]
    fixed: Mapping[str, float]
    initial_states: Mapping[str, float]
    initial_state_stderr: Mapping[str, float]
    time: FloatArray
    output_names: tuple[str, ...]
    channels: Mapping[str, str]
    measured: FloatArray
    reconstructed: FloatArray
    states: FloatArray
    true_outputs: FloatArray
    state_names: tuple[str, ...]
    error_bars: str
    identifiable: bool
    unidentifiable: tuple[tuple[str, ...], ...]
    success: bool
    message: str
    n_passes: int
    gravity: float
    input_noise: Mapping[str, float]
    measured_states: tuple[str, ...] = ()
    scale_pivots: Mapping[str, float] = dataclasses.field(default_factory=dict)
    degrees_of_freedom: Mapping[str, float] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in (
            "parameters",
            "stderr",
            "fixed",
            "initial_states",
            "initial_state_stderr",
            "input_noise",
            "scale_pivots",
            "degrees_of_freedom",
        ):
            set_(self, name, frozen_mapping(getattr(self, name)))
        set_(self, "channels", frozen_mapping(self.channels))
        for name in ("covariance", "time", "measured", "reconstructed", "states", "true_outputs"):
            set_(self, name, frozen_array(getattr(self, name)))
        set_(self, "parameter_names", tuple(self.parameter_names))
        set_(self, "output_names", tuple(self.output_names))
        set_(self, "state_names", tuple(self.state_names))
        set_(self, "measured_states", tuple(self.measured_states))
        set_(self, "unidentifiable", tuple(tuple(c) for c in self.unidentifiable))

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    @property
    def residuals(self) -> FloatArray:
        """Measured minus reconstructed sensor readings, shape (n_t, n_y)."""
        out = np.asarray(self.measured - self.reconstructed)
        out.setflags(write=False)
        return out

    @property
    def correlation(self) -> FloatArray:
        """Correlation matrix of the estimates."""
        return _correlation_of(self)

    @property
    def all_parameters(self) -> Mapping[str, float]:
        """Estimated and fixed sensor parameters together."""
        merged = dict(self.fixed)
        merged.update(self.parameters)
        return frozen_mapping(merged)

    def channel(self, name: str) -> tuple[FloatArray, FloatArray]:
        """``(measured, reconstructed)`` history of one fitted output."""
        if name not in self.output_names:
            raise ChannelError(
                f"output {name!r} was not fitted; fitted outputs: {list(self.output_names)}"
            )
        j = self.output_names.index(name)
        return self.measured[:, j], self.reconstructed[:, j]

    def summary(self) -> str:
        """Markdown tables: sensor errors with standard errors, initial state, fit per channel."""
        rows = []
        for n in self.parameter_names:
            unit = _parameter_unit(n)
            rows.append((n, fmt(self.parameters[n]), fmt(self.stderr[n]), unit))
        given = [(n, fmt(v), "given", _parameter_unit(n)) for n, v in self.fixed.items() if v]
        table = markdown_table(("parameter", "estimate", "std. error", "unit"), rows + given)
        x0_rows = [
            (s, fmt(v), fmt(self.initial_state_stderr.get(s, float("nan"))))
            for s, v in self.initial_states.items()
        ]
        x0_table = markdown_table(("initial state", "value", "std. error"), x0_rows)
        fit_rows = []
        res = self.residuals
        for j, n in enumerate(self.output_names):
            fit_rows.append(
                (
                    n,
                    self.channels.get(n, n),
                    fmt(float(np.sqrt(np.mean(res[:, j] ** 2)))),
                    fmt(float(np.mean(res[:, j]))),
                    _UNITS[n],
                )
            )
        fit_table = markdown_table(("output", "channel", "RMS residual", "mean", "unit"), fit_rows)
        kind = (
            "corrected for coloured residuals"
            if self.error_bars == "colored"
            else "classical (white residuals)"
        )
        notes = [
            f"Data compatibility over {self.time.size} samples: {self.n_passes} output-error "
            f"pass(es); standard errors {kind}."
        ]
        if self.measured_states:
            notes.append(
                f"States taken from their measurements: {', '.join(self.measured_states)}."
            )
        pivoted = {o: v for o, v in self.scale_pivots.items() if v}
        if pivoted:
            notes.append(
                "Scale factors act on the change from the start value: "
                + ", ".join(f"{o} about {fmt(v)}" for o, v in pivoted.items())
                + "."
            )
        if not self.success:
            notes.append(f"**Not converged:** {self.message}")
        if not self.identifiable:
            combos = "; ".join(" + ".join(c) for c in self.unidentifiable) or "see covariance"
            notes.append(f"**Not identifiable:** the data cannot separate {combos}.")
        return "\n\n".join([table, x0_table, fit_table, "\n".join(notes)])

    def plot(self) -> Any:
        """Measured vs reconstructed channels with residuals. Returns a matplotlib Figure."""
        return _plot(self)


# `IdentificationResult.correlation` reads nothing but ``covariance``: one computation serves both.
_correlation_of: Callable[[Any], FloatArray] = vars(IdentificationResult)["correlation"].fget


def _parameter_unit(name: str) -> str:
    if name in _WIND:
        return "m/s"
    kind, _, channel = name.partition("_")
    if kind == "k":
        return "-"
    if kind == "tau":
        return "s"
    return _UNITS.get(channel, "")


def _plot(result: CompatibilityResult) -> Any:
    from ..reports.plotting import figure  # matplotlib on first use only

    names = list(result.output_names)
    fig, axes = figure(2 * len(names), height=1.8, hgap=0.5)
    t = result.time
    res = result.residuals
    for j, name in enumerate(names):
        ax = axes[2 * j, 0]
        ax.plot(t, result.measured[:, j], color="0.55", lw=1.0, label="measured")
        ax.plot(t, result.reconstructed[:, j], color="C0", lw=1.3, label="reconstructed")
        ax.set_ylabel(f"{name} [{_UNITS[name]}]")
        rms = float(np.sqrt(np.mean(res[:, j] ** 2)))
        ax.set_title(f"{name}: RMS residual {rms:.3g} {_UNITS[name]}", fontsize=9, loc="left")
        ax.legend(loc="upper right", fontsize=8)
        rax = axes[2 * j + 1, 0]
        rax.plot(t, res[:, j], color="C3", lw=0.9)
        rax.axhline(0.0, color="k", lw=0.6)
        rax.set_ylabel(f"{name} residual")
    axes[-1, 0].set_xlabel("time [s]")
    return fig


# -- the analysis ------------------------------------------------------------------------
