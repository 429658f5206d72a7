"""The `IdentificationResult` record, apart from `identify` so that the estimators
that build it (`_output_error`, `_filter_error`) need not import the dispatcher."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import (
    IntervalMixin,
    ReadOnlyDict,
    fmt,
    frozen_array,
    frozen_mapping,
    markdown_table,
)
from .._units import parameter_units

__all__ = ["STATE_BIAS_PREFIX", "IdentificationResult"]

FloatArray = NDArray[np.float64]

# the prefix of a state bias's parameter name (``bias.alpha``)
STATE_BIAS_PREFIX = "bias."


@dataclass(frozen=True, eq=False)
class IdentificationResult(IntervalMixin):
    """Estimated parameters with their uncertainty and fit diagnostics.

    Attributes
    ----------
    parameters : mapping of str to float
        The estimated parameters (names in `parameter_names`).
    stderr : mapping of str to float
        Standard errors shown to users; see `error_bars` for which kind.
    covariance : ndarray, shape (n_p, n_p)
        Parameter covariance matching `stderr`, in `parameter_names` order.
    parameter_names : tuple of str
    fixed : mapping of str to float
        Model parameters held at given values (not estimated).
    covariance_white : ndarray, shape (n_p, n_p)
        Classical Cramér–Rao covariance that assumes white residuals.
    error_bars : str
        ``"colored"`` when `covariance` is corrected for residual
        autocorrelation, ``"white"`` when it is the classical one (asked for,
        or because the residuals were found white).
    identifiable : bool
        False when the data cannot separate some parameters.
    unidentifiable : tuple of tuple of str
        The parameter combinations the data cannot separate.
    success : bool
        True when the optimiser converged.
    message : str
    n_iterations : int
    cost : float
        Final value of the minimised objective.
    method : str
        ``"output_error"`` or ``"filter_error"``.
    output_names : tuple of str
        Outputs that entered the fit.
    noise_covariance : ndarray, shape (n_y, n_y)
        Measurement-noise covariance used (estimated from residuals unless given).
    initial_states : tuple of mapping
        Initial state per manoeuvre (estimated or fixed).
    biases : tuple of mapping
        Per manoeuvre, the estimated biases (empty when not estimated): output
        biases keyed by the output's name, state-equation biases (constants
        added to a state's derivative) keyed ``"state.<name>"``.
    extra_stderr : mapping of str to float
        Standard errors of estimated initial states and biases, keyed
        ``"x0[i].state"``, ``"bias[i].output"`` and ``"bias[i].state.<name>"``.
    full_covariance : ndarray, shape (n, n)
        The covariance of every estimate together, in `full_names` order: the
        parameters (as `covariance`), then the initial states, biases and noise
        levels of `extra_stderr`. A sum such as a moment constant plus an
        output bias that stands for it has standard error
        ``sqrt(w' C w)``. Empty on records made before it existed.
    full_names : tuple of str
        The names of `full_covariance`'s rows: `parameter_names`, then the
        keys of `extra_stderr`.
    degrees_of_freedom : mapping of str to float
        Per estimate (parameters and the `extra_stderr` names), the degrees of
        freedom of its standard error: observations less estimates for white
        bars; for coloured bars the Satterthwaite count of the residual
        spectrum they rest on (few when the residuals are slow). `interval`
        and `margin` take Student's t quantile with it; ``inf`` (or absent)
        means the normal quantile.
    residuals : tuple of ndarray
        Per manoeuvre, measured minus model outputs, shape (n_t, n_y).
    sigma2 : float or None
        Filter error only: mean normalised innovation variance (≈ 1 when the
        noise specification is consistent with the data).
    process_noise : mapping of str to float
        Filter error only: process-noise intensities used or estimated.
    model_name : str
    data_fingerprints : tuple of str
        Per manoeuvre, a SHA-256 of the record fitted (time and channels):
        `validate`, `filter_states`, `frequency_response`, `sensitivities`
        and `infer`, given this result and one of those records, start from
        the state the fit used for it; other records start from their own
        measured state.
    bounds : mapping of str to tuple of float
        The bounds the fit used, ``name -> (lower, upper)`` with ``-inf`` /
        ``inf`` for a side left open (empty when none were given).
    active_bounds : mapping of str to str
        Parameters that ended at a bound, ``name -> "lower"`` or ``"upper"``.
        Their standard error is reported as 0 and their row and column of
        `covariance` (and `covariance_white`) are zero: the error bars are
        conditional on the bound, i.e. the other parameters' covariance is
        that of a fit with these parameters held fixed at their bounds (the
        information matrix without their rows and columns).
    time_delays : mapping of str to float
        Estimated pure time delay (s) per delayed control (``time_delays=`` of
        `identify`); each is also a parameter ``"tau_<control>"`` in
        `parameters`, `stderr` and `covariance` (not in `all_parameters`,
        which holds model parameters only).
    parameter_units : mapping of str to str
        Units of the estimated parameters where the model declares them (the
        `aeroid.models.aircraft` models do; ``tau_<control>`` is in s), for labels.
    response_to_noise : mapping of str to float
        Per output, the RMS of the fitted response (about its mean) over the
        RMS of the residual: below one on every output, the record holds no
        manoeuvre and `identify` warns that it is not excited.
    units : mapping of str to str
        Units of the fitted outputs and the controls: the records' own, else those
        the model declares (as `ValidationResult.units`); the report guesses the
        units of parameters the model declares none for from them.
    """

    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    parameter_names: tuple[str, ...]
    fixed: Mapping[str, float]
    covariance_white: FloatArray
    error_bars: str
    identifiable: bool
    unidentifiable: tuple[tuple[str, ...], ...]
    success: bool
    message: str
    n_iterations: int
    cost: float
    method: str
    output_names: tuple[str, ...]
    noise_covariance: FloatArray
    initial_states: tuple[Mapping[str, float], ...] = ()
    biases: tuple[Mapping[str, float], ...] = ()
    extra_stderr: Mapping[str, float] = field(default_factory=dict)
    full_covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    full_names: tuple[str, ...] = ()
    degrees_of_freedom: Mapping[str, float] = field(default_factory=dict)
    residuals: tuple[FloatArray, ...] = ()
    sigma2: float | None = None
    process_noise: Mapping[str, float] = field(default_factory=dict)
    model_name: str = ""
    data_fingerprints: tuple[str, ...] = ()
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    active_bounds: Mapping[str, str] = field(default_factory=dict)
    time_delays: Mapping[str, float] = field(default_factory=dict)
    parameter_units: Mapping[str, str] = field(default_factory=dict)
    response_to_noise: Mapping[str, float] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "time_delays", frozen_mapping(self.time_delays))
        set_(
            self,
            "parameter_units",
            ReadOnlyDict({str(k): str(v) for k, v in self.parameter_units.items()}),
        )
        set_(self, "units", ReadOnlyDict({str(k): str(v) for k, v in self.units.items()}))
        set_(self, "data_fingerprints", tuple(str(f) for f in self.data_fingerprints))
        set_(
            self,
            "bounds",
            ReadOnlyDict({str(k): (float(lo), float(hi)) for k, (lo, hi) in self.bounds.items()}),
        )
        set_(
            self,
            "active_bounds",
            ReadOnlyDict({str(k): str(v) for k, v in self.active_bounds.items()}),
        )
        set_(self, "parameters", frozen_mapping(self.parameters))
        set_(self, "stderr", frozen_mapping(self.stderr))
        set_(self, "fixed", frozen_mapping(self.fixed))
        set_(self, "extra_stderr", frozen_mapping(self.extra_stderr))
        set_(self, "degrees_of_freedom", frozen_mapping(self.degrees_of_freedom))
        set_(self, "response_to_noise", frozen_mapping(self.response_to_noise))
        set_(self, "process_noise", frozen_mapping(self.process_noise))
        set_(self, "covariance", frozen_array(self.covariance))
        set_(self, "full_covariance", frozen_array(self.full_covariance))
        set_(self, "full_names", tuple(self.full_names))
        set_(self, "covariance_white", frozen_array(self.covariance_white))
        set_(self, "noise_covariance", frozen_array(self.noise_covariance))
        set_(self, "parameter_names", tuple(self.parameter_names))
        set_(self, "output_names", tuple(self.output_names))
        set_(self, "unidentifiable", tuple(tuple(c) for c in self.unidentifiable))
        set_(self, "initial_states", tuple(frozen_mapping(m) for m in self.initial_states))
        set_(self, "biases", tuple(frozen_mapping(m) for m in self.biases))
        set_(self, "residuals", tuple(frozen_array(r) for r in self.residuals))

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    @property
    def correlation(self) -> FloatArray:
        """Parameter correlation matrix derived from `covariance`."""
        d = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.covariance / np.outer(d, d)
        c[~np.isfinite(c)] = 0.0  # a parameter held at a bound varies with none
        # one the data cannot separate: its correlations are unknown, not zero
        unknown = ~np.isfinite(d)
        c[unknown, :] = np.nan
        c[:, unknown] = np.nan
        np.fill_diagonal(c, 1.0)
        c.setflags(write=False)
        return c

    def _margin_stderr(self) -> Mapping[str, float]:
        # `margin` covers the initial states and biases of `extra_stderr` too
        return {**self.extra_stderr, **self.stderr}

    def _interval_values(self) -> Mapping[str, float]:
        # ... and so does `interval`, centred on their estimates
        extra = {
            f"{kind}[{i}].{n}": float(v)
            for kind, per_record in (("x0", self.initial_states), ("bias", self.biases))
            for i, values in enumerate(per_record)
            for n, v in values.items()
        }
        return {**extra, **self.parameters}

    @property
    def stderr_white(self) -> Mapping[str, float]:
        """Classical (white-residual) standard errors."""
        d = np.sqrt(np.clip(np.diag(self.covariance_white), 0.0, None))
        return ReadOnlyDict({n: float(s) for n, s in zip(self.parameter_names, d, strict=True)})

    @property
    def all_parameters(self) -> Mapping[str, float]:
        """Fixed and estimated parameters together (a full model parameter set)."""
        merged: dict[str, Any] = dict(self.fixed)
        delays = {f"tau_{c}" for c in self.time_delays}
        merged.update({k: v for k, v in self.parameters.items() if k not in delays})
        return ReadOnlyDict(merged)

    def plot(self, **kwargs: Any) -> Any:
        """Residual histories and estimates with 95 % error bars. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_identification

        return plot_identification(self, **kwargs)

    def _nuisance_rows(self, with_biases: bool) -> list[tuple[str, str, str]]:
        """(name, estimate, std. error) of the estimated output and state biases and of
        the filter-error noise levels, named as in `extra_stderr`. Initial states are
        left out: every output-error fit estimates them, as a start, not a result."""
        rows = []
        if with_biases:
            for i, values in enumerate(self.biases):
                for n, est in values.items():
                    se = self.extra_stderr.get(f"bias[{i}].{n}", float("nan"))
                    rows.append((f"bias[{i}].{n}", fmt(est), fmt(se)))
        # a noise level given (not estimated) has no standard error: it is no estimate
        for n, est in self.process_noise.items():
            if f"process_noise.{n}" in self.extra_stderr:
                rows.append(
                    (f"process_noise.{n}", fmt(est), fmt(self.extra_stderr[f"process_noise.{n}"]))
                )
        for j, n in enumerate(self.output_names):
            key = f"measurement_noise.{n}"
            if key in self.extra_stderr and j < self.noise_covariance.shape[0]:
                rows.append(
                    (key, fmt(float(self.noise_covariance[j, j])), fmt(self.extra_stderr[key]))
                )
        return rows

    def _units_shown(self) -> dict[str, str]:
        """The parameters' units: declared, else guessed (and marked so) where the
        record's channel units make the guess right (`guessed_units`)."""
        declared = self.parameter_units
        units = parameter_units(self.parameter_names, declared, self.units)
        return {n: u if n in declared else f"{u} (guessed)" for n, u in units.items()}

    def summary(self) -> str:
        """Markdown table of estimates, standard errors and relative errors (and units:
        the model's, else guessed from the names and the record's channel units, as the
        report gives them), then one of the estimated biases and noise levels (where
        the fit estimated any)."""
        units = self._units_shown()
        rows = []
        for n in self.parameter_names:
            est = self.parameters[n]
            se = self.stderr[n]
            at = self.active_bounds.get(n)
            rel = f"{100 * se / abs(est):.1f}%" if est != 0 and np.isfinite(se) and not at else "—"
            row = [n, *([units.get(n, "—")] if units else []), fmt(est), fmt(se), rel]
            if self.bounds:
                if n in self.bounds:
                    lo, hi = self.bounds[n]
                    row.append(f"[{fmt(lo)}, {fmt(hi)}]" + (f" **at {at}**" if at else ""))
                else:
                    row.append("—")
            rows.append(tuple(row))
        if not rows:  # the model held whole: the table shows what was fitted instead
            for kind, per_record in (("x0", self.initial_states), ("bias", self.biases)):
                for i, values in enumerate(per_record):
                    for n, est in values.items():
                        key = f"{kind}[{i}].{n}"
                        if key in self.extra_stderr:
                            rows.append((key, fmt(est), fmt(self.extra_stderr[key]), "—"))
        header: tuple[str, ...] = ("parameter", "estimate", "std. error", "rel. error")
        if units and self.parameter_names:
            header = ("parameter", "unit", *header[1:])
        if self.bounds:
            header = (*header, "bounds")
        table = markdown_table(header, rows)
        # the held-whole table above already lists the biases
        extra = self._nuisance_rows(with_biases=bool(self.parameter_names))
        if extra:
            table += "\n\n" + markdown_table(
                ("bias or noise level", "estimate", "std. error"), extra
            )
            table += "\n\n" + _nuisance_legend([r[0] for r in extra])
        notes = []
        if self.active_bounds:
            held = ", ".join(f"{n} ({side})" for n, side in self.active_bounds.items())
            notes.append(
                f"At a bound: {held}; held there, so its standard error is shown as 0 and "
                "the others' are conditional on the bound."
            )
        kind = (
            "corrected for coloured residuals"
            if self.error_bars == "colored"
            else "classical (white residuals)"
        )
        notes.append(f"Standard errors: {kind}; method: {self.method.replace('_', ' ')}.")
        if self.output_names:
            notes.append(f"Outputs fitted: {', '.join(self.output_names)}.")
        if self.time_delays:
            which = ", ".join(f"tau_{c} of {c}" for c in self.time_delays)
            notes.append(f"Time delays (s), the controls entering as u(t - tau): {which}.")
        if self.sigma2 is not None:
            notes.append(f"Normalised innovation variance sigma2 = {self.sigma2:.3g}.")
        if not self.success:
            notes.append(f"**Not converged:** {self.message}")
        if not self.identifiable:
            combos = "; ".join(" + ".join(c) for c in self.unidentifiable) or "see covariance"
            notes.append(f"**Not identifiable:** the data cannot separate {combos}.")
        return table + "\n\n" + "\n".join(notes)


# what each kind of row of the biases-and-noise table is, and its unit
_NUISANCE_KINDS = (
    ("bias[", ".state.", "bias[i].state.x: a constant added to dx/dt on record i, x's unit/s"),
    ("bias[", "", "bias[i].y: the bias of output y on record i, in y's unit"),
    (
        "process_noise.",
        "",
        "process_noise.x: the process-noise intensity of state x, (x's unit)²/s",
    ),
    (
        "measurement_noise.",
        "",
        "measurement_noise.y: the measurement-noise variance of y, (y's unit)²",
    ),
)


def _nuisance_legend(names: list[str]) -> str:
    """One line that says what the rows present are and in which unit."""
    said: list[str] = []
    for name in names:
        text = next(
            t for head, inner, t in _NUISANCE_KINDS if name.startswith(head) and inner in name
        )
        if text not in said:
            said.append(text)
    return "; ".join(said) + "."
