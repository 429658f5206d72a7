"""The `InferenceResult` record, apart from `aeroid.uncertainty.inference` so that its
helpers need not import the entry points (which re-export it)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import as_float
from .._records import FrozenState, fmt, frozen_array, frozen_mapping, markdown_table
from ..errors import InferenceError
from .sampler import ChainState

FloatArray = NDArray[np.float64]

#: Percentile levels reported in `InferenceResult.percentiles`.
PERCENTILES = (2.5, 50.0, 97.5)
# how the summary names each move
_MOVE_NAMES = {
    "de": "differential-evolution",
    "demcz": "differential-evolution (archive, DE-MCz)",
    "stretch": "stretch",
}


@dataclass(frozen=True, eq=False)
class InferenceResult(FrozenState):
    """Posterior samples of `infer`, their summaries and convergence diagnostics.

    Attributes
    ----------
    samples : ndarray, shape (n_samples, n_parameters)
        Posterior draws after burn-in and thinning (read-only), ensemble by
        ensemble, step by step, walker by walker.
    parameter_names : tuple of str
        Column names of `samples`: the inferred model parameters in the
        order given, then the estimated ``sigma_<output>`` noise levels.
    parameters : mapping of str to float
        Posterior means (a point estimate that `validate`, `propagate` and
        friends accept like a least-squares fit).
    stderr : mapping of str to float
        Posterior standard deviations.
    covariance : ndarray, shape (n_parameters, n_parameters)
        Posterior sample covariance.
    percentiles : mapping of str to ndarray of shape (3,)
        Per parameter, the 2.5th, 50th and 97.5th percentiles (the median and
        the central 95 % credible interval); deprecated shape, kept for one
        release: read `percentile_table`, the shape every result shares.
    map_parameters : mapping of str to float
        The draw with the highest posterior density.
    r_hat : mapping of str to float
        Split-R-hat; with several ensembles the larger of the value across
        all walkers and the value across ensembles.
    effective_sample_size : mapping of str to float
        Number of draws over the integrated autocorrelation time.
    autocorrelation_time : mapping of str to float
        Integrated autocorrelation time in sampler steps.
    acceptance_fraction : float
        Mean fraction of accepted proposals per walker.
    log_prob : ndarray, shape (n_samples,)
        Log-posterior (up to the evidence) of each draw.
    fixed : mapping of str to float
        Model parameters not inferred (held at their nominal values).
    noise_parameters : tuple of str
        Names among `parameter_names` that are estimated noise standard deviations.
    chain : tuple of ChainState
        Final state of each ensemble; pass the result as ``initial`` to
        `infer` to continue sampling where it ended.
    output_names : tuple of str
    noise : mapping of str to float
        Noise standard deviations that were given (not estimated).
    priors : mapping of str to str
    n_walkers, n_steps, burn_in, thin, n_ensembles : int
    stretch : float
    move : str
        The sampler's move, ``"stretch"``, ``"de"`` or ``"demcz"``.
    converged : bool
        False when the chains are shorter than 50 autocorrelation times or
        an R-hat exceeds 1.05 (a `UserWarning` was issued).
    message : str
        Why the run is or is not considered converged.
    backend : str
    model_name : str
    residual_correlation : mapping of str to float
        Per output, the lag-one correlation of the residuals at the best draw
        (`infer` only; empty from `combine_ensembles`). The likelihood counts
        the samples as independent: residuals correlated well beyond chance
        make the posterior too narrow, and `infer` warns.
    residual_samples : int
        The samples that correlation was computed over.
    """

    samples: FloatArray
    parameter_names: tuple[str, ...]
    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    percentiles: Mapping[str, FloatArray]
    map_parameters: Mapping[str, float]
    r_hat: Mapping[str, float]
    effective_sample_size: Mapping[str, float]
    autocorrelation_time: Mapping[str, float]
    acceptance_fraction: float
    log_prob: FloatArray
    fixed: Mapping[str, float]
    noise_parameters: tuple[str, ...]
    chain: tuple[ChainState, ...]
    output_names: tuple[str, ...]
    noise: Mapping[str, float]
    priors: Mapping[str, str]
    n_walkers: int
    n_steps: int
    burn_in: int
    thin: int
    n_ensembles: int
    stretch: float
    converged: bool
    message: str
    backend: str = "numpy"
    model_name: str = ""
    move: str = "stretch"
    residual_correlation: Mapping[str, float] = field(default_factory=dict)
    residual_samples: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "samples", frozen_array(self.samples))
        set_(self, "log_prob", frozen_array(self.log_prob))
        set_(self, "covariance", frozen_array(self.covariance))
        for name in ("parameter_names", "noise_parameters", "output_names"):
            set_(self, name, tuple(str(n) for n in getattr(self, name)))
        for name in (
            "parameters",
            "stderr",
            "map_parameters",
            "r_hat",
            "effective_sample_size",
            "autocorrelation_time",
            "fixed",
            "noise",
            "priors",
            "residual_correlation",
        ):
            set_(self, name, frozen_mapping(getattr(self, name)))
        set_(
            self,
            "percentiles",
            frozen_mapping({k: frozen_array(v) for k, v in dict(self.percentiles).items()}),
        )
        set_(self, "chain", tuple(self.chain))
        for name in ("n_walkers", "n_steps", "burn_in", "thin", "n_ensembles"):
            set_(self, name, int(getattr(self, name)))
        set_(self, "acceptance_fraction", float(self.acceptance_fraction))
        set_(self, "stretch", float(self.stretch))
        set_(self, "converged", bool(self.converged))
        set_(self, "residual_samples", int(self.residual_samples))

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    def interval(self, level: float = 0.95) -> Mapping[str, tuple[float, float]]:
        """Each parameter's central `level` credible interval from the posterior
        samples, ``name -> (lower, upper)``."""
        value = as_float(level)  # a parameter's name is no level
        if value is None or not 0.0 < value < 1.0:
            raise InferenceError(f"level must lie strictly between 0 and 1, got {level!r}")
        level = value
        samples = np.asarray(self.samples, dtype=np.float64).reshape(-1, len(self.parameter_names))
        lo, hi = np.quantile(samples, [0.5 - level / 2, 0.5 + level / 2], axis=0)
        return MappingProxyType(
            {n: (float(lo[j]), float(hi[j])) for j, n in enumerate(self.parameter_names)}
        )

    def margin(self, level: float = 0.95) -> Mapping[str, float]:
        """Half-width of each parameter's central `level` credible interval."""
        return MappingProxyType({n: (hi - lo) / 2 for n, (lo, hi) in self.interval(level).items()})

    @property
    def percentile_table(self) -> Mapping[str, Mapping[float, float]]:
        """The percentiles as every result gives them: parameter -> level (percent) -> value
        (``{"M_q": {2.5: ..., 50.0: ..., 97.5: ...}}``)."""
        return MappingProxyType(
            {
                n: MappingProxyType({p: float(v) for p, v in zip(PERCENTILES, row, strict=True)})
                for n, row in self.percentiles.items()
            }
        )

    @property
    def all_parameters(self) -> Mapping[str, float]:
        """Fixed model parameters together with the posterior means of the inferred ones."""
        merged = dict(self.fixed)
        merged.update({k: v for k, v in self.parameters.items() if k not in self.noise_parameters})
        return frozen_mapping(merged)

    def sample(self, name: str) -> FloatArray:
        """All draws of one parameter."""
        if name not in self.parameter_names:
            raise InferenceError(
                f"parameter {name!r} was not inferred; inferred: {list(self.parameter_names)}"
            )
        return self.samples[:, self.parameter_names.index(name)]

    def plot(self, **kwargs: Any) -> Any:
        """Corner plot of the posterior. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_posterior

        return plot_posterior(self, **kwargs)

    def plot_traces(self) -> Any:
        """Sample traces per parameter. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_traces

        return plot_traces(self)

    def summary(self) -> str:
        """Markdown: posterior means, standard deviations, 95 % intervals, R-hat and ESS."""
        rows = []
        levels = self.percentile_table
        for n in self.parameter_names:
            lo, med, hi = levels[n].values()
            rows.append(
                (
                    n,
                    fmt(self.parameters[n]),
                    fmt(self.stderr[n]),
                    fmt(float(lo)),
                    fmt(float(med)),
                    fmt(float(hi)),
                    f"{self.r_hat[n]:.3f}" if math.isfinite(self.r_hat[n]) else "—",
                    f"{self.effective_sample_size[n]:.0f}",
                )
            )
        table = markdown_table(
            ("parameter", "mean", "std. dev.", "P2.5", "P50", "P97.5", "R-hat", "ESS"), rows
        )
        ens = f"{self.n_ensembles} ensembles × " if self.n_ensembles > 1 else ""
        notes = [
            f"Posterior from {self.samples.shape[0]} draws: {ens}{self.n_walkers} walkers, "
            f"{self.n_steps} steps ({self.burn_in} burn-in, thin {self.thin}"
            f"; {_MOVE_NAMES.get(self.move, self.move)} move); "
            f"acceptance fraction {self.acceptance_fraction:.2f}; "
            f"longest autocorrelation time {_max_finite(self.autocorrelation_time)} steps.",
        ]
        if self.noise_parameters:
            notes.append("Sensor noise estimated: " + ", ".join(self.noise_parameters) + ".")
        if self.noise:
            notes.append(
                "Sensor noise given (std. dev.): "
                + ", ".join(f"{k} {fmt(v)}" for k, v in self.noise.items())
                + "."
            )
        if self.fixed:
            notes.append(
                "Fixed: " + ", ".join(f"{k} = {fmt(v)}" for k, v in self.fixed.items()) + "."
            )
        coloured = coloured_outputs(self.residual_correlation, self.residual_samples)
        if coloured:
            notes.append(
                "**Coloured residuals** at the best draw (lag-one correlation "
                + ", ".join(f"{k} {v:.2f}" for k, v in coloured.items())
                + "): the likelihood counts the samples as independent, so this posterior "
                f"is too narrow, by up to about {widening(coloured):.1f}x."
            )
        if self.converged:
            notes.append(f"Converged: {self.message}")
        else:
            notes.append(f"**Not converged:** {self.message}")
        return table + "\n\n" + "\n".join(notes)


# A lag-one residual correlation is reported as colour where it widens a slow
# parameter's bar by more than this (AR(1): sqrt((1 + rho) / (1 - rho))) ...
_WIDENING = 1.25
# ... and lies beyond chance: this many standard errors (1 / sqrt(n)) of white noise's.
_CHANCE = 4.0


def coloured_outputs(correlation: Mapping[str, float], n: int) -> dict[str, float]:
    """The outputs whose residuals' lag-one correlation widens a slow parameter's bar by
    more than `_WIDENING` and lies beyond chance for `n` samples."""
    rho = (_WIDENING**2 - 1.0) / (_WIDENING**2 + 1.0)
    limit = max(rho, _CHANCE / math.sqrt(max(n, 1)))
    return {k: float(v) for k, v in correlation.items() if math.isfinite(v) and v > limit}


def widening(coloured: Mapping[str, float]) -> float:
    """AR(1)'s factor on a slow parameter's standard error at the largest correlation."""
    rho = min(max(coloured.values()), 0.9999)
    return math.sqrt((1.0 + rho) / (1.0 - rho))


def _max_finite(values: Mapping[str, float]) -> str:
    v = [x for x in values.values() if math.isfinite(x)]
    return fmt(max(v)) if v else "—"
