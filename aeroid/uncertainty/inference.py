"""Bayesian parameter inference: `infer` and its `InferenceResult`.

The posterior of the inferred parameters (and, by default, of one sensor-noise
standard deviation ``sigma_<output>`` per output) given a flight record is
sampled with the affine-invariant ensemble sampler of `aeroid.uncertainty.sampler`. The
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._colour import _lag_one
from .._records import FrozenState, frozen_mapping
from .._threads import small_blas
from ..errors import InferenceError
from ..io.data import FlightData, check_flag
from ..models.model import fitted_start
from ._inference_record import PERCENTILES as PERCENTILES
from ._inference_record import InferenceResult as InferenceResult
from ._inference_record import _max_finite as _max_finite
from ._inference_record import coloured_outputs, widening
from ._posterior import _BACKENDS as _BACKENDS
from ._posterior import _BALL_NOISE as _BALL_NOISE
from ._posterior import _BALL_PRIOR as _BALL_PRIOR
from ._posterior import _BALL_STDERR as _BALL_STDERR
from ._posterior import _JAX_OPTIONS as _JAX_OPTIONS
from ._posterior import _SIM_OPTIONS as _SIM_OPTIONS
from ._posterior import NOISE_HI as NOISE_HI
from ._posterior import NOISE_LO as NOISE_LO
from ._posterior import _default_noise_prior as _default_noise_prior
from ._posterior import _Posterior as _Posterior
from ._posterior import _StartFailure as _StartFailure
from .priors import Prior
from .sampler import (
    INIT_TAG,
    ChainState,
    SamplerRun,
    _chain_table,
    _identity,
    _run_line,
    _sample,
    _stream,
    autocorrelation_time,
    check_walkers,
    effective_sample_size,
    seed_sequence,
    split_r_hat,
)

__all__ = ["EnsembleRun", "InferenceResult", "combine_ensembles", "infer", "infer_ensemble"]

FloatArray = NDArray[np.float64]

#: A chain is called converged when it is at least this many autocorrelation times long ...
MIN_STEPS_PER_TAU = 50.0
#: ... and no split-R-hat exceeds this.
MAX_R_HAT = 1.05
# Differential evolution decorrelates 3-5x faster than the stretch move on the near-Gaussian,
# correlated posteriors of a few derivatives and noise levels (tests/test_sampler.py).
_DEFAULT_MOVE = "de"
# Differential evolution proposes from the other half's differences: with 8 walkers a
# half, six parameters' chains ran 25-33 steps per autocorrelation time, so the
# documented 2000 steps converged for half the seeds; 16 a half gives 18-24.
_MIN_WALKERS = 32
# Most float64 values one chain or one batched simulation may hold (2 GiB).
_MAX_VALUES = 2**28


# -- records ------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EnsembleRun(FrozenState):
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
    # the residuals' lag-one correlation at this ensemble's best draw, and their count
    residual_correlation: Mapping[str, float] = field(default_factory=dict)
    residual_samples: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("ensemble", "residual_samples"):
            set_(self, name, int(getattr(self, name)))
        for name in ("parameter_names", "noise_parameters", "output_names"):
            set_(self, name, tuple(str(n) for n in getattr(self, name)))
        for name in ("fixed", "noise", "priors", "residual_correlation"):
            set_(self, name, frozen_mapping(getattr(self, name)))

    def summary(self) -> str:
        """Markdown: this ensemble's draws per parameter (mean, standard deviation, 95 %
        interval, split R-hat, ESS) and how it ran."""
        table = _chain_table(self.sampler.chain, list(self.parameter_names))
        return (
            f"{table}\n\nEnsemble {self.ensemble} of model `{self.model_name}`. "
            f"{_run_line(self.sampler)} One ensemble of several: `aeroid.combine_ensembles` "
            "pools them into the posterior and judges its convergence."
        )

    def plot(self, **kwargs: Any) -> Any:
        """Walker traces, one panel a parameter. Returns a matplotlib Figure."""
        from ..reports.chain_plots import plot_chain

        return plot_chain(self.sampler.chain, self.parameter_names, **kwargs)


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
    if resume and move is not None and move != initial.move:
        # a continued chain keeps its move, so that it equals one longer run
        raise InferenceError(
            f"move: the stored chain was sampled with move {initial.move!r}, got {move!r}; "
            "a continued chain keeps its move (leave move out to continue it)"
        )
    if move is None:
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
    # the sampler scores two half-ensembles a step, or the whole ensemble ("demcz")
    whole = move == "demcz"
    post.expect(n_steps if whole else 2 * n_steps)
    start: FloatArray | ChainState
    if resume:
        walkers = initial.chain[0].positions.shape[0] if initial.chain else 0
        post._jax_batch = (walkers if whole else walkers // 2) or None
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
        post._jax_batch = nw if whole else nw // 2  # every batch the sampler scores
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
    # the start's log-probabilities were just scored (or checked, continuing) on `post`
    run = _sample(
        post,
        start,
        n_steps,
        seed=seed,
        stretch=stretch,
        move=move,
        burn_in=burn_in,
        thin=thin,
        progress=progress,
        rescore=False,
    )
    flat = run.chain.reshape(-1, len(post.names))
    best = flat[int(np.argmax(run.log_prob.reshape(-1)))]
    rho, n_res = _residual_colour(post, {**post.fixed, **dict(zip(post.names, best, strict=True))})
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
        rho,
        n_res,
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
    lp = post._score(np.array(state.positions))
    stored = np.asarray(state.log_prob)
    same = np.isclose(lp, stored, rtol=1e-8, atol=1e-8) | (np.isneginf(lp) & np.isneginf(stored))
    if not np.all(same):
        raise InferenceError(
            "initial: the stored chain's log-probabilities do not match this model, data and "
            "options; continue a chain only on the problem it was sampled on"
        )
    return state


def _problem(
    model: Any,
    data: FlightData,
    parameters: Mapping[str, Prior],
    *,
    outputs: Sequence[str] | None,
    noise: Mapping[str, float] | None,
    x0: Any,
    initial: Any,
    seed: int | np.random.SeedSequence | None,
    backend: str,
    simulate_options: Mapping[str, Any] | None,
) -> tuple[_Posterior, np.random.SeedSequence | None]:
    """The posterior `infer` and `infer_ensemble` sample, and the root of their random
    streams (None: a continued chain resumes its stored streams)."""
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
    return post, root


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
    post, root = _problem(
        model,
        data,
        parameters,
        outputs=outputs,
        noise=noise,
        x0=x0,
        initial=initial,
        seed=seed,
        backend=backend,
        simulate_options=simulate_options,
    )
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
    move : {"de", "demcz", "stretch"}, optional
        The ensemble move: differential evolution (ter Braak 2006; the
        default), differential evolution from an archive of past states
        (``"demcz"``, ter Braak & Vrugt 2008: all walkers scored in one
        batched simulation a step instead of two, and shorter
        autocorrelation times; it needs a burn-in that reaches the
        posterior's bulk), or Goodman & Weare's affine-invariant stretch. On
        the near-Gaussian, correlated posteriors of a few aerodynamic
        derivatives and noise levels, differential evolution's
        autocorrelation time is several times shorter than the stretch
        move's (`aeroid.uncertainty.sampler`), so 2000 steps converge where
        the stretch move needs several times more. A continued chain
        (``initial=`` an `InferenceResult`) keeps the move it was sampled with:
        leave `move` out (or give that move) to continue it.

    Returns
    -------
    InferenceResult

    Raises
    ------
    InferenceError
        Bad priors, names, noise or options (among them text or a bool where
        a number or a bool is expected, invalid `simulate_options`); a chain
        continued with another move, walker count or parameters; a chain
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
    post, root = _problem(
        model,
        data,
        parameters,
        outputs=outputs,
        noise=noise,
        x0=x0,
        initial=initial,
        seed=seed,
        backend=backend,
        simulate_options=simulate_options,
    )
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


def _residual_colour(post: _Posterior, values: Mapping[str, float]) -> tuple[dict[str, float], int]:
    """Each output's lag-one residual correlation at `values`, and the samples it is over:
    the likelihood counts the samples as independent, which coloured noise (turbulence,
    unmodelled dynamics) is not."""
    res = post.residuals(values)
    rho = _lag_one([res - res.mean(axis=0)])
    return dict(zip(post.output_names, rho.tolist(), strict=True)), int(res.shape[0])


# What two ensembles of one problem share; `_combine` names every entry that differs.
_PROBLEM_KEYS: dict[str, Callable[[EnsembleRun], Any]] = {
    "parameters": lambda r: r.parameter_names,
    "walkers": lambda r: r.sampler.chain.shape,
    "steps": lambda r: (r.sampler.n_steps, r.sampler.burn_in, r.sampler.thin),
    "move": lambda r: (r.sampler.move, r.sampler.stretch),
    "outputs": lambda r: r.output_names,
    "noise": lambda r: (r.noise_parameters, dict(r.noise)),
    "priors": lambda r: dict(r.priors),
    "fixed parameters": lambda r: dict(r.fixed),
    "backend": lambda r: r.backend,
    "model": lambda r: r.model_name,
}


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
    if isinstance(runs, (str, bytes)) or not hasattr(runs, "__iter__"):
        raise InferenceError(f"runs: expected a sequence of EnsembleRun, got {type(runs).__name__}")
    runs = list(runs)
    strays = [type(r).__name__ for r in runs if not isinstance(r, EnsembleRun)]
    if not runs or strays:
        raise InferenceError(
            "runs: expected a non-empty sequence of EnsembleRun"
            + (f", got {strays[0]} among them" if strays else "")
        )
    runs = sorted(runs, key=lambda r: r.ensemble)
    first = runs[0]
    index = [r.ensemble for r in runs]
    if len(set(index)) != len(index):
        raise InferenceError(f"runs: ensemble indices repeat: {index}")
    for r in runs[1:]:
        differ = [what for what, key in _PROBLEM_KEYS.items() if key(r) != key(first)]
        if differ:
            raise InferenceError(
                f"runs: ensemble {r.ensemble} differs from ensemble {first.ensemble} in "
                f"{', '.join(differ)}; only ensembles of one problem and options can be combined"
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
    # the residuals at the best draw: the ensemble that holds it measured them
    holder = runs[int(np.argmax([np.max(r.sampler.log_prob) for r in runs]))]
    coloured = coloured_outputs(holder.residual_correlation, holder.residual_samples)
    if coloured and warn:
        listing = ", ".join(f"{k!r} {v:.2f}" for k, v in coloured.items())
        warnings.warn(
            f"infer: the residuals at the best draw are coloured (lag-one correlation "
            f"{listing}); the likelihood counts the samples as independent, so the posterior "
            f"is too narrow, by up to about {widening(coloured):.1f}x for slow parameters. "
            "identify's error bars correct for coloured residuals; turbulence is process "
            "noise (identify(method='filter_error'))",
            UserWarning,
            stacklevel=stacklevel,
        )
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
        residual_correlation=holder.residual_correlation,
        residual_samples=holder.residual_samples,
    )
