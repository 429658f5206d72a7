"""Bayesian parameter inference: `infer` and its `InferenceResult`.

The posterior of the inferred parameters (and, by default, of one sensor-noise
standard deviation ``sigma_<output>`` per output) given a flight record is
sampled with the affine-invariant ensemble sampler of `aeroid.sampler`. The
likelihood of a whole half-ensemble of proposals is one batched simulation
(`Model.simulate_batch`, or a vmapped JAX rollout with ``backend="jax"``).

Running ensembles in parallel (for the pipeline)
------------------------------------------------
``infer(..., n_ensembles=k, seed=s)`` is exactly::

    runs = [infer_ensemble(..., seed=s, ensemble=e) for e in range(k)]
    combine_ensembles(runs)

`infer_ensemble` runs one ensemble and returns a storable `EnsembleRun`; it
takes the same problem arguments as `infer` plus the ensemble's index, and its
random streams depend only on ``(seed, ensemble)``, so ensembles can run on
different workers in any order. `combine_ensembles` pools the runs, computes
the diagnostics (R-hat across walkers and across ensembles) and issues the
convergence warning.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._records import fmt, frozen_array, frozen_mapping, markdown_table
from ._threads import small_blas
from .data import FlightData, as_float, check_flag, measured_start
from .errors import InferenceError, SimulationError
from .model import (
    SIMULATE_OPTION_KEYS,
    Model,
    check_integrator,
    check_simulate_options,
    fitted_start,
    require_model,
)
from .priors import LogUniform, Prior
from .sampler import (
    INIT_TAG,
    ChainState,
    SamplerRun,
    _identity,
    _stream,
    autocorrelation_time,
    check_walkers,
    effective_sample_size,
    ensemble_sampler,
    seed_sequence,
    split_r_hat,
)

__all__ = ["EnsembleRun", "InferenceResult", "combine_ensembles", "infer", "infer_ensemble"]

FloatArray = NDArray[np.float64]

#: Percentile levels reported in `InferenceResult.percentiles`.
PERCENTILES = (2.5, 50.0, 97.5)
#: A chain is called converged when it is at least this many autocorrelation times long ...
MIN_STEPS_PER_TAU = 50.0
#: ... and no split-R-hat exceeds this.
MAX_R_HAT = 1.05
#: Default noise prior: LogUniform(NOISE_LO * s, NOISE_HI * s), s = RMS of the output about its mean.
NOISE_LO = 1e-6
NOISE_HI = 10.0
# Starting balls: fraction of the identification stderr, of the prior scale, of a noise level.
_BALL_STDERR = 0.5
_BALL_PRIOR = 0.01
_BALL_NOISE = 0.05
# Differential evolution decorrelates 3-5x faster than the stretch move on the near-Gaussian,
# correlated posteriors of a few derivatives and noise levels (tests/test_sampler.py).
_DEFAULT_MOVE = "de"
# Differential evolution proposes from the other half's differences: with 8 walkers a
# half, six parameters' chains ran 25-33 steps per autocorrelation time, so the
# documented 2000 steps converged for half the seeds; 16 a half gives 18-24.
_MIN_WALKERS = 32
_SIM_OPTIONS = SIMULATE_OPTION_KEYS
# Most float64 values one chain or one batched simulation may hold (2 GiB).
_MAX_VALUES = 2**28
_JAX_OPTIONS = ("substeps",)
_BACKENDS = ("numpy", "jax")


# -- records ------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EnsembleRun:
    """One ensemble's samples and final state, with what is needed to pool ensembles.

    Attributes
    ----------
    ensemble : int
        Index of the ensemble within its seed's family.
    parameter_names : tuple of str
        Sampled parameters (model parameters, then ``sigma_<output>`` noise levels).
    sampler : SamplerRun
        Kept chain (n_kept, n_walkers, n_dim), log-probabilities, acceptance
        counts and final `ChainState`.
    fixed : mapping of str to float
        Model parameters held at their nominal values.
    noise_parameters : tuple of str
        Which of `parameter_names` are estimated noise standard deviations.
    output_names : tuple of str
        Outputs in the likelihood.
    noise : mapping of str to float
        Noise standard deviations given by the caller (outputs not listed are estimated).
    priors : mapping of str to str
        The prior of each parameter, as text.
    backend : str
    model_name : str
    """

    ensemble: int
    parameter_names: tuple[str, ...]
    sampler: SamplerRun
    fixed: Mapping[str, float]
    noise_parameters: tuple[str, ...]
    output_names: tuple[str, ...]
    noise: Mapping[str, float]
    priors: Mapping[str, str]
    backend: str
    model_name: str

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "ensemble", int(self.ensemble))
        for name in ("parameter_names", "noise_parameters", "output_names"):
            set_(self, name, tuple(str(n) for n in getattr(self, name)))
        for name in ("fixed", "noise", "priors"):
            set_(self, name, frozen_mapping(getattr(self, name)))


@dataclass(frozen=True, eq=False)
class InferenceResult:
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
        The sampler's move, ``"stretch"`` or ``"de"``.
    converged : bool
        False when the chains are shorter than 50 autocorrelation times or
        an R-hat exceeds 1.05 (a `UserWarning` was issued).
    message : str
        Why the run is or is not considered converged.
    backend : str
    model_name : str
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

    @property
    def standard_errors(self) -> Mapping[str, float]:
        """The `stderr` (the name every estimator's result shares)."""
        return self.stderr

    def interval(self, level: float = 0.95) -> Mapping[str, tuple[float, float]]:
        """Each parameter's central `level` credible interval from the posterior
        samples, ``name -> (lower, upper)``."""
        if not 0.0 < level < 1.0:
            raise InferenceError(f"level must lie strictly between 0 and 1, got {level!r}")
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
        from .plotting import plot_posterior

        return plot_posterior(self, **kwargs)

    def plot_traces(self) -> Any:
        """Sample traces per parameter. Returns a matplotlib Figure."""
        from .plotting import plot_traces

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
            f"; {'differential-evolution' if self.move == 'de' else 'stretch'} move); "
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
        if self.converged:
            notes.append(f"Converged: {self.message}")
        else:
            notes.append(f"**Not converged:** {self.message}")
        return table + "\n\n" + "\n".join(notes)


def _max_finite(values: Mapping[str, float]) -> str:
    v = [x for x in values.values() if math.isfinite(x)]
    return fmt(max(v)) if v else "—"


# -- the problem ------------------------------------------------------------------------------


class _StartFailure(SimulationError, InferenceError):
    """The model gives non-finite values at the starting point of the walkers.

    A `SimulationError` like every such failure, and an `InferenceError` as
    `infer` raised before for a start where every simulation failed.
    """


class _Posterior:
    """Log-posterior of a batch of parameter vectors for one model and record."""

    def __init__(
        self,
        model: Any,
        data: FlightData,
        parameters: Mapping[str, Prior],
        *,
        outputs: Sequence[str] | None,
        noise: Mapping[str, float] | None,
        x0: Any,
        backend: str,
        simulate_options: Mapping[str, Any] | None,
    ) -> None:
        if not isinstance(data, FlightData):
            raise InferenceError(f"data: expected aeroid.FlightData, got {type(data).__name__}")
        require_model(model, InferenceError)
        self.batched = isinstance(model, Model)
        if backend not in _BACKENDS:
            raise InferenceError(f"backend: expected one of {list(_BACKENDS)}, got {backend!r}")
        if backend == "jax" and not self.batched:
            raise InferenceError(
                f"backend='jax' needs an aeroid.Model with a continuous dynamics callable; "
                f"model {getattr(model, 'name', '?')!r} is a stepped simulator "
                f"({type(model).__name__}); use backend='numpy'"
            )
        self.model = model
        self.backend = backend
        self.model_name = str(getattr(model, "name", ""))
        model_outputs = tuple(model.output_names if self.batched else model.outputs)

        # outputs entering the likelihood
        if outputs is None:
            outs = model_outputs
        else:
            outs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
            bad = [o for o in outs if o not in model_outputs]
            if bad or not outs or len(set(outs)) != len(outs):
                raise InferenceError(
                    f"outputs: expected distinct names among the model's outputs "
                    f"{list(model_outputs)}, got {list(outs)}"
                )
        data.require(outs, role="output")
        self.output_names = outs
        self.out_index = np.array([model_outputs.index(o) for o in outs], dtype=np.int64)
        self.time = np.array(data.time)
        self.y = data.array(list(outs)).astype(np.float64)  # (n_t, n_y)
        self.data = data

        # parameters and priors
        if not isinstance(parameters, Mapping) or not parameters:
            raise InferenceError(
                "parameters: expected a non-empty dict of parameter name -> prior, e.g. "
                "{'M_alpha': aeroid.Normal(-4, 2)}"
            )
        model_params = dict(model.parameters)
        given_noise = self._check_noise(noise, outs)
        noise_name = {o: f"sigma_{o}" for o in outs if o not in given_noise}
        clash = sorted(n for n in noise_name.values() if n in model_params)
        if clash:
            raise InferenceError(
                f"noise parameter names {clash} clash with model parameters; give the noise "
                "of those outputs with noise={...}"
            )
        valid = [*model_params, *noise_name.values()]
        names: list[str] = []
        priors: list[Prior] = []
        for name, prior in parameters.items():
            if name not in valid:
                hint = ""
                if name.startswith("sigma_") and name[6:] in given_noise:
                    hint = f" (the noise of {name[6:]!r} is given with noise=)"
                raise InferenceError(
                    f"parameters: {name!r} is neither a parameter of model {self.model_name!r} "
                    f"nor an estimated noise level{hint}; valid names: {valid}"
                )
            if not isinstance(prior, Prior):
                raise InferenceError(
                    f"parameters[{name!r}]: expected a prior (aeroid.Normal, Uniform, "
                    f"LogUniform, HalfNormal or a Prior subclass), got {prior!r}"
                )
            names.append(name)
            priors.append(prior)
        for o, n in noise_name.items():
            if n not in names:
                names.append(n)
                priors.append(_default_noise_prior(self.y[:, outs.index(o)]))
        self.names = tuple(names)
        self.priors = tuple(priors)
        self.n_dim = len(names)
        self.model_cols = [(n, i) for i, n in enumerate(names) if n in model_params]
        self.noise_parameters = tuple(n for n in names if n not in model_params)
        # per output: column of theta holding its sigma, or -1 with a fixed value
        self.sigma_col = np.array(
            [names.index(noise_name[o]) if o in noise_name else -1 for o in outs], dtype=np.int64
        )
        self.sigma_fixed = np.array([given_noise.get(o, np.nan) for o in outs])
        self.noise = given_noise
        self.fixed = {k: v for k, v in model_params.items() if k not in names}
        self.n_t = self.time.size
        self.const = 0.5 * self.n_t * len(outs) * math.log(2.0 * math.pi)

        # simulation set-up
        if simulate_options is not None and not isinstance(simulate_options, Mapping):
            raise InferenceError(
                f"simulate_options: expected a dict, got {type(simulate_options).__name__}"
            )
        opts = dict(simulate_options or {})
        if self.batched:
            allowed = _JAX_OPTIONS if backend == "jax" else _SIM_OPTIONS
            unknown = sorted(set(opts) - set(allowed))
            if unknown:
                raise InferenceError(
                    f"simulate_options: unknown options {unknown} for backend {backend!r}; "
                    f"valid: {list(allowed)}"
                )
            data.require(model.controls, role="control")
            self.controls = model.control_array(self.time, data)[0]
            if x0 is None:
                x0 = measured_start(data, model.states)
            self.x0 = model.initial_state(x0, 1)[0]
            if backend == "numpy":
                opts.setdefault("method", "auto")
                # here, naming the option: in the likelihood a bad one is a rejected member
                check_simulate_options(opts, model, InferenceError)
            elif opts.get("substeps") is not None:
                check_integrator(
                    "rk4",
                    opts["substeps"],
                    1e-9,
                    1e-12,
                    error=InferenceError,
                    prefix="simulate_options",
                )
        else:
            self.x0 = x0
        self.options = opts
        self.last_error: Exception | None = None
        self._jax_batch: int | None = None

    @staticmethod
    def _check_noise(noise: Mapping[str, float] | None, outs: tuple[str, ...]) -> dict[str, float]:
        if noise is None:
            return {}
        if not isinstance(noise, Mapping):
            raise InferenceError(
                f"noise: expected a dict of output -> standard deviation, got {noise!r}"
            )
        out: dict[str, float] = {}
        for k, v in noise.items():
            if k not in outs:
                raise InferenceError(
                    f"noise: {k!r} is not an output in the likelihood; outputs: {list(outs)}"
                )
            s = as_float(v)
            if s is None or not (s > 0.0 and math.isfinite(s)):
                raise InferenceError(f"noise[{k!r}]: expected a standard deviation > 0, got {v!r}")
            out[str(k)] = s
        return out

    # -- simulation of a batch ------------------------------------------------------------
    def simulate(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        """Outputs (batch, n_t, n_y) of the likelihood's outputs; failed members are NaN."""
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            if not self.batched:
                return self._loop(params, batch)
            if self.backend == "jax":
                return self._jax(params, batch)
            try:
                return self._numpy(params)
            except Exception as exc:  # one bad member must not sink the batch
                self.last_error = exc
                if batch == 1:
                    return np.full((1, self.n_t, len(self.output_names)), np.nan)
            rows = []
            for b in range(batch):
                one = {k: v[b : b + 1] for k, v in params.items()}
                try:
                    rows.append(self._numpy(one)[0])
                except Exception as exc:
                    self.last_error = exc
                    rows.append(np.full((self.n_t, len(self.output_names)), np.nan))
            return np.stack(rows)

    def _numpy(self, params: Mapping[str, FloatArray]) -> FloatArray:
        res = self.model.simulate_batch(self.time, self.controls, self.x0, params, **self.options)
        y = res.outputs[:, :, self.out_index]
        y[~res.ok] = np.nan
        return np.asarray(y)

    def _jax(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        from . import _jax

        # pad to one batch size so the vmapped rollout compiles once
        size = self._jax_batch = max(self._jax_batch or 0, batch)
        padded = {k: np.concatenate([v, np.repeat(v[:1], size - batch)]) for k, v in params.items()}
        y = _jax.batch_outputs(
            self.model,
            self.time,
            self.controls,
            self.x0,
            padded,
            substeps=self.options.get("substeps"),
        )
        return np.asarray(y)[:batch][:, :, self.out_index]

    def _loop(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        out = np.full((batch, self.n_t, len(self.output_names)), np.nan)
        for b in range(batch):
            p = {k: float(v[b]) for k, v in params.items()}
            try:
                res = self.model.simulate_data(self.data, x0=self.x0, parameters=p, **self.options)
                out[b] = np.column_stack([res.output(o) for o in self.output_names])
            except Exception as exc:  # a failing member is a rejected proposal
                self.last_error = exc
        return out

    # -- densities ------------------------------------------------------------------------
    def log_prior(self, theta: FloatArray) -> FloatArray:
        lp = np.zeros(theta.shape[0])
        with np.errstate(all="ignore"):
            for i, prior in enumerate(self.priors):
                lp = lp + np.asarray(prior.log_pdf(theta[:, i]), dtype=np.float64)
        return np.where(np.isfinite(lp), lp, -np.inf)

    def sigmas(self, theta: FloatArray) -> FloatArray:
        sig = np.broadcast_to(self.sigma_fixed, (theta.shape[0], self.sigma_fixed.size)).copy()
        est = self.sigma_col >= 0
        sig[:, est] = theta[:, self.sigma_col[est]]
        return sig

    def log_likelihood(self, theta: FloatArray) -> FloatArray:
        batch = theta.shape[0]
        params = {n: np.ascontiguousarray(theta[:, i]) for n, i in self.model_cols}
        y = self.simulate(params, batch)
        with np.errstate(all="ignore"):
            r = y - self.y[None]
            ss = np.einsum("btj,btj->bj", r, r)
            sig = self.sigmas(theta)
            ll = -self.n_t * np.log(sig).sum(axis=1) - 0.5 * (ss / sig**2).sum(axis=1)
            ll = ll - self.const
        return np.where(np.isfinite(ll) & np.all(sig > 0, axis=1), ll, -np.inf)

    def __call__(self, theta: FloatArray) -> FloatArray:
        theta = np.asarray(theta, dtype=np.float64)
        lp = self.log_prior(theta)
        good = np.flatnonzero(np.isfinite(lp))
        if good.size:
            lp[good] = lp[good] + self.log_likelihood(theta[good])
        return np.where(np.isfinite(lp), lp, -np.inf)

    # -- starting points --------------------------------------------------------------------
    def require_simulates(self, center: FloatArray) -> None:
        """Raise `SimulationError` (naming the state or output and the time) when the
        model gives non-finite values at the starting point; a walker elsewhere that
        fails is only a rejected point."""
        if not self.batched:
            return
        values = {n: np.array([center[i]]) for n, i in self.model_cols}
        res = self.model.simulate_batch(
            self.time, self.controls, self.x0, values, **{"method": "auto", **self.options}
        )
        if not res.ok[0]:
            start = {n: float(center[i]) for n, i in self.model_cols}
            raise _StartFailure(
                f"infer: model {self.model.name!r} cannot be simulated at the starting point "
                f"{start}: {res.failure[0]}"
            )

    def residual_rms(self, values: Mapping[str, float]) -> FloatArray:
        """RMS residual per output at one parameter set (NaN where the simulation fails)."""
        params = {n: np.array([values[n]]) for n, _ in self.model_cols}
        y = self.simulate(params, 1)[0]
        with np.errstate(all="ignore"):
            return np.asarray(np.sqrt(np.mean((y - self.y) ** 2, axis=0)))

    def start_ball(self, initial: Any) -> tuple[FloatArray, FloatArray]:
        """Centre (n_dim,) and a square-root covariance (n_dim, n_dim) of the starting ball."""
        center = np.full(self.n_dim, np.nan)
        root = np.zeros((self.n_dim, self.n_dim))
        names = self.names
        model_names = [n for n, _ in self.model_cols]
        if initial is None:
            given: dict[str, float] = {}
            for n in model_names:
                nominal = float(self.model.parameters[n])
                prior = self.priors[names.index(n)]
                given[n] = nominal if np.isfinite(prior.log_pdf(nominal)) else prior.center
        elif isinstance(initial, Mapping):
            given = {}
            for k, v in initial.items():
                if k not in names:
                    raise InferenceError(
                        f"initial: {k!r} is not an inferred parameter; inferred: {list(names)}"
                    )
                value = as_float(v)
                if value is None:
                    raise InferenceError(f"initial[{k!r}]: expected a number, got {v!r}")
                given[k] = value
                if not math.isfinite(value):
                    raise InferenceError(f"initial[{k!r}]: value {v!r} is not finite")
        elif hasattr(initial, "parameters"):
            given = self._from_fit(initial, center, root)
        else:
            raise InferenceError(
                "initial: expected None, a dict of starting values, an identification result "
                f"or an InferenceResult to continue, got {type(initial).__name__}"
            )
        for n, v in given.items():
            i = names.index(n)
            center[i] = v
            if root[i, i] == 0.0:
                prior = self.priors[i]
                if n in self.noise_parameters:
                    root[i, i] = _BALL_NOISE * abs(v)
                else:
                    root[i, i] = _BALL_PRIOR * prior.scale
        # model parameters nobody gave: the prior's centre
        for i, n in enumerate(names):
            if n not in self.noise_parameters and not np.isfinite(center[i]):
                center[i] = self.priors[i].center
                root[i, i] = _BALL_PRIOR * self.priors[i].scale
        # noise levels nobody gave: the residual RMS at the centre
        missing = [
            i for i, n in enumerate(names) if n in self.noise_parameters and np.isnan(center[i])
        ]
        if missing:
            values = {n: center[i] for n, i in self.model_cols}
            rms = self.residual_rms(values)
            for i in missing:
                j = int(np.flatnonzero(self.sigma_col == i)[0])
                s = float(rms[j])
                if not (s > 0.0 and math.isfinite(s)):
                    s = float(np.std(self.y[:, j])) or 1.0
                lo, hi = self.priors[i].support
                s = min(max(s, lo), hi)
                center[i] = s
                root[i, i] = _BALL_NOISE * s
        # a degenerate ball cannot be stretched open: give every direction some width
        for i in range(self.n_dim):
            if not root[i, i] > 0.0:
                root[i, i] = _BALL_PRIOR * (abs(center[i]) or 1.0)
        return center, root

    def _from_fit(self, fit: Any, center: FloatArray, root: FloatArray) -> dict[str, float]:
        """Centre on a fit's estimates, ball from its covariance (or standard errors)."""
        values = fit.parameters if isinstance(fit.parameters, Mapping) else {}
        stderr = getattr(fit, "stderr", {}) or {}
        given: dict[str, float] = {}
        idx: list[int] = []
        for i, n in enumerate(self.names):
            if n in values and math.isfinite(float(values[n])):
                given[n] = float(values[n])
                center[i] = given[n]
                idx.append(i)
        # covariance block of the parameters the fit estimated
        cov = getattr(fit, "covariance", None)
        fit_names = tuple(getattr(fit, "parameter_names", ()))
        sub = [n for n in (self.names[i] for i in idx) if n in fit_names]
        done = False
        if cov is not None and sub and len(sub) == len(idx):
            c = np.asarray(cov, dtype=np.float64)
            if c.shape == (len(fit_names), len(fit_names)):
                cols = [fit_names.index(n) for n in sub]
                block = c[np.ix_(cols, cols)]
                try:
                    chol = np.linalg.cholesky(block)
                    if np.all(np.isfinite(chol)):
                        root[np.ix_(idx, idx)] = _BALL_STDERR * chol
                        done = True
                except np.linalg.LinAlgError:
                    pass
        if not done:
            for i in idx:
                s = stderr.get(self.names[i], np.nan) if isinstance(stderr, Mapping) else np.nan
                s = float(s)
                if s > 0 and math.isfinite(s):
                    root[i, i] = _BALL_STDERR * s
        # noise levels from the fit's noise covariance (variances)
        noise_cov = getattr(fit, "noise_covariance", None)
        fit_outs = tuple(getattr(fit, "output_names", ()))
        if noise_cov is not None and fit_outs:
            nc = np.asarray(noise_cov, dtype=np.float64)
            for j, o in enumerate(self.output_names):
                col = int(self.sigma_col[j])
                if col < 0 or self.names[col] in given or o not in fit_outs:
                    continue
                k = fit_outs.index(o)
                if nc.ndim == 2 and nc.shape[0] > k and nc[k, k] > 0 and math.isfinite(nc[k, k]):
                    s = math.sqrt(float(nc[k, k]))
                    given[self.names[col]] = s
                    center[col] = s
                    # a standard deviation estimated from n_t residuals is good to 1/sqrt(2 n_t)
                    root[col, col] = max(s / math.sqrt(2.0 * self.n_t), 1e-3 * s)
        return given

    def draw_start(
        self, rng: np.random.Generator, n_walkers: int, center: FloatArray, root: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Walkers in the ball; walkers at impossible points are redrawn a few times."""
        x = center + rng.standard_normal((n_walkers, self.n_dim)) @ root.T
        lp = self._score_halves(x)
        shrink = 1.0
        for _ in range(10):
            bad = np.flatnonzero(~np.isfinite(lp))
            if bad.size == 0:
                break
            shrink *= 0.5
            x[bad] = center + shrink * rng.standard_normal((bad.size, self.n_dim)) @ root.T
            lp[bad] = self._score(x[bad])
        return x, lp

    def _score(self, theta: FloatArray) -> FloatArray:
        half = max(1, self._jax_batch or theta.shape[0])
        return np.concatenate([self(theta[i : i + half]) for i in range(0, theta.shape[0], half)])

    def _score_halves(self, x: FloatArray) -> FloatArray:
        h = x.shape[0] // 2
        return np.concatenate([self(x[:h]), self(x[h:])])


def _default_noise_prior(y: FloatArray) -> Prior:
    s = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
    if not (s > 0.0 and math.isfinite(s)):
        s = 1.0
    return LogUniform(NOISE_LO * s, NOISE_HI * s)


# -- running ----------------------------------------------------------------------------------


def _check_count(name: str, value: Any, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InferenceError(f"{name}: expected an integer >= {lo}, got {value!r}")
    return int(value)


def _check_chain_size(n_steps: int, burn_in: int, thin: int, walkers: int, n_dim: int) -> None:
    """Refuse a chain whose stored draws (and log-probabilities) would not fit in memory,
    before any sampling: the sampler allocates them all up front."""
    n_kept = (n_steps - burn_in) // thin
    values = n_kept * walkers * (n_dim + 1)
    if values > _MAX_VALUES:
        raise InferenceError(
            f"n_steps: keeping {n_kept} steps of {walkers} walkers ({values} values, at most "
            f"{_MAX_VALUES}) would not fit in memory; use fewer n_steps or a larger thin"
        )


def _ensemble_seed(root: np.random.SeedSequence, ensemble: int) -> np.random.SeedSequence:
    entropy, key = _identity(root)
    return np.random.SeedSequence(entropy, spawn_key=(*key, int(ensemble)))


def _run(
    post: _Posterior,
    *,
    initial: Any,
    n_walkers: int | None,
    n_steps: int,
    burn_in: int | None,
    thin: int,
    stretch: float,
    root: np.random.SeedSequence | None,
    ensemble: int,
    progress: bool,
    move: str | None = None,
) -> EnsembleRun:
    n_steps = _check_count("n_steps", n_steps, 1)
    thin = _check_count("thin", thin, 1)
    resume = isinstance(initial, InferenceResult)
    if move is None:
        # a continued chain keeps its move, so that it equals one longer run
        move = initial.move if resume else _DEFAULT_MOVE
    if burn_in is None:
        burn_in = 0 if resume else n_steps // 4
    burn_in = _check_count("burn_in", burn_in, 0)
    if burn_in >= n_steps:
        raise InferenceError(f"burn_in ({burn_in}) must be smaller than n_steps ({n_steps})")
    if (n_steps - burn_in) // thin < 1:
        raise InferenceError(
            f"no draws kept: n_steps - burn_in = {n_steps - burn_in} with thin = {thin}"
        )
    start: FloatArray | ChainState
    if resume:
        state = _resume_state(post, initial, ensemble, n_walkers)
        _check_chain_size(n_steps, burn_in, thin, state.positions.shape[0], post.n_dim)
        start = state
        seed = None if root is None else _ensemble_seed(root, ensemble)
    else:
        default = max(2 * post.n_dim + 2, _MIN_WALKERS)
        nw = check_walkers(default if n_walkers is None else n_walkers, post.n_dim)
        # each half-ensemble is one batched simulation of every output at every sample
        batch_values = nw * post.n_t * max(len(post.output_names), 1)
        if batch_values > _MAX_VALUES:
            raise InferenceError(
                f"n_walkers: {nw} walkers would simulate {batch_values} output values at "
                f"once (at most {_MAX_VALUES}); use fewer walkers"
            )
        _check_chain_size(n_steps, burn_in, thin, nw, post.n_dim)
        ss = _ensemble_seed(root if root is not None else seed_sequence(None), ensemble)
        entropy, key = _identity(ss)
        post._jax_batch = nw // 2  # every batch the sampler scores has this size
        center, sqrt_cov = post.start_ball(initial)
        post.require_simulates(center)
        x, lp = post.draw_start(_stream(entropy, key, INIT_TAG), nw, center, sqrt_cov)
        if not np.any(np.isfinite(lp)):
            cause = f"; last simulation error: {post.last_error}" if post.last_error else ""
            raise InferenceError(
                "no walker starts at a point with finite posterior density: the starting "
                f"ball around {dict(zip(post.names, np.round(center, 6).tolist(), strict=True))} "
                f"is outside the priors' support or every simulation there failed{cause}"
            )
        start = ChainState(x, lp, 0, entropy, key)
        seed = None
    run = ensemble_sampler(
        post,
        start,
        n_steps,
        seed=seed,
        stretch=stretch,
        move=move,
        burn_in=burn_in,
        thin=thin,
        progress=progress,
    )
    return EnsembleRun(
        ensemble,
        post.names,
        run,
        post.fixed,
        post.noise_parameters,
        post.output_names,
        post.noise,
        {n: repr(p) for n, p in zip(post.names, post.priors, strict=True)},
        post.backend,
        post.model_name,
    )


def _resume_state(
    post: _Posterior, previous: InferenceResult, ensemble: int, n_walkers: int | None
) -> ChainState:
    if previous.parameter_names != post.names:
        raise InferenceError(
            f"initial: the stored chain sampled {list(previous.parameter_names)}, this problem "
            f"samples {list(post.names)}; give the same parameters and noise options to continue"
        )
    if not 0 <= ensemble < len(previous.chain):
        raise InferenceError(
            f"ensemble {ensemble}: the stored result holds {len(previous.chain)} ensemble(s)"
        )
    state = previous.chain[ensemble]
    if n_walkers is not None and n_walkers != state.positions.shape[0]:
        raise InferenceError(
            f"n_walkers: the stored chain has {state.positions.shape[0]} walkers, got {n_walkers}"
        )
    # the stored log-probabilities are reused (exact continuation); check they still hold
    lp = post._score_halves(np.array(state.positions))
    stored = np.asarray(state.log_prob)
    same = np.isclose(lp, stored, rtol=1e-8, atol=1e-8) | (np.isneginf(lp) & np.isneginf(stored))
    if not np.all(same):
        raise InferenceError(
            "initial: the stored chain's log-probabilities do not match this model, data and "
            "options; continue a chain only on the problem it was sampled on"
        )
    return state


def infer_ensemble(
    model: Any,
    data: FlightData,
    parameters: Mapping[str, Prior],
    *,
    ensemble: int = 0,
    outputs: Sequence[str] | None = None,
    noise: Mapping[str, float] | None = None,
    x0: Any = None,
    initial: Any = None,
    n_walkers: int | None = None,
    n_steps: int = 2000,
    burn_in: int | None = None,
    thin: int = 1,
    stretch: float = 2.0,
    seed: int | np.random.SeedSequence | None = None,
    backend: str = "numpy",
    simulate_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    move: str | None = None,
) -> EnsembleRun:
    """Run ensemble number `ensemble` of an `infer` call (for parallel execution).

    Takes `infer`'s arguments (except ``n_ensembles``). Ensemble ``e`` draws
    its random numbers from ``SeedSequence(entropy, spawn_key=(*key, e))``
    of the `seed` specification, so ``combine_ensembles([infer_ensemble(...,
    ensemble=e) for e in range(k)])`` equals ``infer(..., n_ensembles=k)``
    bit for bit, whatever worker runs which ensemble. ``seed=None`` draws
    fresh entropy per call, so give a seed when ensembles run separately.

    Returns
    -------
    EnsembleRun
    """
    ensemble = _check_count("ensemble", ensemble, 0)
    if x0 is None:  # None unless `initial` is a fit of this record
        x0 = fitted_start(initial, data)[0]
    post = _Posterior(
        model,
        data,
        parameters,
        outputs=outputs,
        noise=noise,
        x0=x0,
        backend=backend,
        simulate_options=simulate_options,
    )
    root = None if seed is None and isinstance(initial, InferenceResult) else seed_sequence(seed)
    return _run(
        post,
        initial=initial,
        n_walkers=n_walkers,
        n_steps=n_steps,
        burn_in=burn_in,
        thin=thin,
        stretch=stretch,
        root=root,
        ensemble=ensemble,
        progress=progress,
        move=move,
    )


@small_blas
def infer(
    model: Any,
    data: FlightData,
    parameters: Mapping[str, Prior],
    *,
    outputs: Sequence[str] | None = None,
    noise: Mapping[str, float] | None = None,
    x0: Any = None,
    initial: Any = None,
    n_walkers: int | None = None,
    n_steps: int = 2000,
    burn_in: int | None = None,
    thin: int = 1,
    stretch: float = 2.0,
    seed: int | np.random.SeedSequence | None = None,
    backend: str = "numpy",
    simulate_options: Mapping[str, Any] | None = None,
    n_ensembles: int = 1,
    progress: bool = False,
    move: str | None = None,
) -> InferenceResult:
    """Sample the posterior of model parameters (and sensor noise) given a flight record.

    The likelihood is Gaussian and independent over samples and outputs:
    ``y_j(t) = model output_j(t) + e``, ``e ~ N(0, sigma_j²)``. Each output's
    ``sigma_j`` is a parameter ``sigma_<output>`` inferred along with the
    model parameters unless given with `noise`; its default prior is
    ``LogUniform(1e-6 s, 10 s)`` with ``s`` the RMS of the measured output
    about its mean (a bounded scale-invariant prior; override it by giving a
    prior for ``sigma_<output>`` in `parameters`).

    Parameters
    ----------
    model : Model or SimulatorModel
        A `SimulatorModel` is simulated member by member (numpy backend only).
    data : FlightData
        The record: controls, and the outputs that enter the likelihood.
    parameters : dict of str to Prior
        Parameters to infer with their priors; model parameters not named
        here stay at their nominal values (`InferenceResult.fixed`).
    outputs : sequence of str, optional
        Outputs in the likelihood (default: all the model's outputs).
    noise : dict of str to float, optional
        Measurement-noise standard deviations of outputs; those outputs get
        no ``sigma_<output>`` parameter.
    x0 : array_like or dict, optional
        Initial state (default: the state an identification result given as
        `initial` used for this record, else the measured states at the first
        sample). A chain continued from an `InferenceResult` needs the `x0`
        it was sampled with.
    initial : dict, identification result or InferenceResult, optional
        Where the walkers start. A dict of values: a ball of 1 % of each
        prior's standard deviation around them (5 % for noise levels). An
        identification result: a ball of half its covariance around its
        estimates (noise levels from its noise covariance). An
        `InferenceResult`: continue its chains from their final state (see
        Notes). Default: the model's nominal values (the prior's median
        where the nominal value is outside the prior), noise levels at the
        residual RMS there. Walkers that land on impossible points are
        redrawn from a shrinking ball.
    n_walkers : int, optional
        Walkers per ensemble: even, at least ``2 * n_dim``; default
        ``max(2 * n_dim + 2, 32)``.
    n_steps : int
        Sampler steps per ensemble (each moves every walker once).
    burn_in : int, optional
        Leading steps discarded; default ``n_steps // 4`` (0 when continuing
        a previous result).
    thin : int
        Keep every `thin`-th step after burn-in.
    stretch : float
        Stretch-move scale ``a`` (> 1), for ``move="stretch"``.
    seed : int or SeedSequence, optional
        Same seed, same samples, bit for bit.
    backend : {"numpy", "jax"}
        ``"jax"`` evaluates each half-ensemble with a vmapped, compiled RK4
        rollout (needs an `aeroid.Model` written with ``jax.numpy``).
    simulate_options : dict, optional
        numpy backend: ``method`` (default ``"auto"``), ``substeps``, ``rtol``,
        ``atol`` of `Model.simulate_batch` (any keywords for a
        `SimulatorModel`); jax backend: ``substeps``.
    n_ensembles : int
        Independent ensembles, pooled; R-hat is then also computed across them.
    progress : bool
        Show a progress bar (tqdm).
    move : {"de", "stretch"}, optional
        The ensemble move: differential evolution (ter Braak 2006; the
        default), or Goodman & Weare's affine-invariant stretch. On the
        near-Gaussian, correlated posteriors of a few aerodynamic derivatives
        and noise levels, differential evolution's autocorrelation time is
        several times shorter (`aeroid.sampler`), so 2000 steps converge where
        the stretch move needs several times more. A continued chain
        (``initial=`` an `InferenceResult`) keeps the move it was sampled with.

    Returns
    -------
    InferenceResult

    Raises
    ------
    InferenceError
        Bad priors, names, noise or options (among them text or a bool where
        a number or a bool is expected, invalid `simulate_options`); a chain
        or a walker batch too large to hold in memory; no walker with a finite
        posterior density at the start; ``backend="jax"`` with a simulator.
    ChannelError
        An output or control channel is missing from `data`.

    Warns
    -----
    UserWarning
        The chains have not converged: shorter than 50 autocorrelation times,
        or a split-R-hat above 1.05.

    Notes
    -----
    Every walker's likelihood evaluations for one half-ensemble step are one
    batched simulation; a member whose simulation fails (diverges, raises)
    is a rejected proposal. Continuing from an `InferenceResult` with
    ``seed=None`` resumes each ensemble's random stream where it stopped:
    the walker trajectories are then identical to those of one longer run
    with the original seed, and the draws of the two results concatenate to
    the longer run's when the first run's ``n_steps - burn_in`` is a
    multiple of `thin`. With a seed given, the continuation draws a fresh stream.
    """
    n_ensembles = _check_count("n_ensembles", n_ensembles, 1)
    # text read as a number, or a truthy "no" read as True, would pass unnoticed
    if isinstance(stretch, (bool, np.bool_, str, bytes)):
        raise InferenceError(f"stretch: expected a finite number > 1, got {stretch!r}")
    check_flag(progress, "progress", InferenceError)
    if isinstance(initial, InferenceResult) and len(initial.chain) != n_ensembles:
        if n_ensembles == 1:
            n_ensembles = len(initial.chain)
        else:
            raise InferenceError(
                f"n_ensembles: the stored result holds {len(initial.chain)} ensemble(s), "
                f"got {n_ensembles}"
            )
    if x0 is None:  # None unless `initial` is a fit of this record
        x0 = fitted_start(initial, data)[0]
    post = _Posterior(
        model,
        data,
        parameters,
        outputs=outputs,
        noise=noise,
        x0=x0,
        backend=backend,
        simulate_options=simulate_options,
    )
    root = None if seed is None and isinstance(initial, InferenceResult) else seed_sequence(seed)
    runs = [
        _run(
            post,
            initial=initial,
            n_walkers=n_walkers,
            n_steps=n_steps,
            burn_in=burn_in,
            thin=thin,
            stretch=stretch,
            root=root,
            ensemble=e,
            progress=progress,
            move=move,
        )
        for e in range(n_ensembles)
    ]
    return _combine(runs, stacklevel=4)  # _combine, infer, its BLAS wrapper, the caller


def combine_ensembles(runs: Sequence[EnsembleRun], *, warn: bool = True) -> InferenceResult:
    """Pool ensembles of one problem into an `InferenceResult`.

    Parameters
    ----------
    runs : sequence of EnsembleRun
        Outputs of `infer_ensemble` for the same problem and options (any
        order; they are sorted by ensemble index).
    warn : bool
        Issue the convergence `UserWarning` when the pooled chains have not converged.

    Returns
    -------
    InferenceResult
    """
    return _combine(runs, stacklevel=3, warn=warn)


def _combine(runs: Sequence[EnsembleRun], *, stacklevel: int, warn: bool = True) -> InferenceResult:
    runs = sorted(runs, key=lambda r: r.ensemble)
    if not runs or not all(isinstance(r, EnsembleRun) for r in runs):
        raise InferenceError("runs: expected a non-empty sequence of EnsembleRun")
    first = runs[0]
    index = [r.ensemble for r in runs]
    if len(set(index)) != len(index):
        raise InferenceError(f"runs: ensemble indices repeat: {index}")
    for r in runs[1:]:
        if (
            r.parameter_names != first.parameter_names
            or r.sampler.chain.shape != first.sampler.chain.shape
            or (r.sampler.n_steps, r.sampler.burn_in, r.sampler.thin)
            != (first.sampler.n_steps, first.sampler.burn_in, first.sampler.thin)
            or r.output_names != first.output_names
            or r.sampler.move != first.sampler.move
        ):
            raise InferenceError(
                "runs: ensembles differ in parameters, walkers, steps, move or outputs; "
                "only ensembles of one problem can be combined"
            )
    names = first.parameter_names
    n_dim = len(names)
    chains = np.concatenate([r.sampler.chain for r in runs], axis=1)  # (n_kept, W, d)
    samples = np.concatenate([r.sampler.chain.reshape(-1, n_dim) for r in runs])
    log_prob = np.concatenate([r.sampler.log_prob.reshape(-1) for r in runs])
    n_kept = chains.shape[0]
    thin = first.sampler.thin

    mean = samples.mean(axis=0)
    cov = np.atleast_2d(np.cov(samples.T)) if samples.shape[0] > 1 else np.zeros((n_dim, n_dim))
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    pct = np.percentile(samples, PERCENTILES, axis=0)  # (3, d)
    best = samples[int(np.argmax(log_prob))]

    if n_kept >= 2:
        tau_kept = np.atleast_1d(autocorrelation_time(chains))
        ess = np.atleast_1d(effective_sample_size(chains))
    else:
        tau_kept = np.full(n_dim, np.nan)
        ess = np.full(n_dim, np.nan)
    if n_kept >= 4:
        r_hat = np.atleast_1d(split_r_hat(chains))
        if len(runs) > 1:
            pooled = np.stack(
                [r.sampler.chain.reshape(-1, n_dim) for r in runs], axis=1
            )  # (n_kept * n_walkers, n_ensembles, d), step-major per ensemble
            r_hat = np.fmax(r_hat, np.atleast_1d(split_r_hat(pooled)))
    else:
        r_hat = np.full(n_dim, np.nan)

    problems = []
    worst_tau = float(np.max(tau_kept)) if np.all(np.isfinite(tau_kept)) else math.inf
    if not math.isfinite(worst_tau):
        problems.append("the autocorrelation time could not be estimated")
    elif n_kept < MIN_STEPS_PER_TAU * worst_tau:
        worst = names[int(np.argmax(tau_kept))]
        problems.append(
            f"the kept chain is {n_kept * thin} steps long, shorter than {MIN_STEPS_PER_TAU:g} "
            f"autocorrelation times ({MIN_STEPS_PER_TAU * worst_tau * thin:.0f} steps for "
            f"{worst}, tau = {worst_tau * thin:.3g} steps); run more steps"
        )
    if not np.all(np.isfinite(r_hat)):
        problems.append("R-hat could not be computed")
    elif np.max(r_hat) > MAX_R_HAT:
        bad = [f"{n} ({v:.3f})" for n, v in zip(names, r_hat, strict=True) if v > MAX_R_HAT]
        problems.append(f"split-R-hat above {MAX_R_HAT} for " + ", ".join(bad))
    converged = not problems
    if converged:
        message = (
            f"chain length >= {MIN_STEPS_PER_TAU:g} autocorrelation times and "
            f"split-R-hat <= {MAX_R_HAT} for every parameter"
        )
    else:
        message = "; ".join(problems)
        if warn:
            warnings.warn(
                f"the chain has not converged: {message}", UserWarning, stacklevel=stacklevel
            )

    def named(values: Any) -> dict[str, float]:
        return {n: float(v) for n, v in zip(names, np.ravel(values), strict=True)}

    accept = float(np.mean([r.sampler.acceptance_fraction.mean() for r in runs]))
    return InferenceResult(
        samples=samples,
        parameter_names=names,
        parameters=named(mean),
        stderr=named(sd),
        covariance=cov,
        percentiles={n: pct[:, i] for i, n in enumerate(names)},
        map_parameters=named(best),
        r_hat=named(r_hat),
        effective_sample_size=named(ess),
        autocorrelation_time=named(tau_kept * thin),
        acceptance_fraction=accept,
        log_prob=log_prob,
        fixed=first.fixed,
        noise_parameters=first.noise_parameters,
        chain=tuple(r.sampler.state for r in runs),
        output_names=first.output_names,
        noise=first.noise,
        priors=first.priors,
        n_walkers=first.sampler.chain.shape[1],
        n_steps=first.sampler.n_steps,
        burn_in=first.sampler.burn_in,
        thin=thin,
        n_ensembles=len(runs),
        stretch=first.sampler.stretch,
        move=first.sampler.move,
        converged=converged,
        message=message,
        backend=first.backend,
        model_name=first.model_name,
    )
