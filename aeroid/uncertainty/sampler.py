"""Affine-invariant ensemble MCMC and convergence diagnostics.

The sampler moves the walkers in two halves ("red/blue"), and all proposals
of a half are scored in *one* call of the vectorised log-probability
``log_prob(theta (B, n_dim)) -> (B,)`` (``"demcz"``: all walkers in one
call); a NaN or infinite log-probability is a rejected proposal. Three
moves, all unchanged by any linear reparameterisation:

- ``"stretch"`` (Goodman & Weare 2010): every walker proposes a point on the
  line through itself and a random walker of the other half.
- ``"de"``, differential evolution (ter Braak 2006): every walker moves by
  ``gamma`` times the difference of two distinct walkers of the other half,
  with ``gamma = 2.38 / sqrt(2 n_dim)`` and, one proposal in ten, ``gamma =
  1`` (a jump between modes). On near-Gaussian posteriors of a few
  parameters its autocorrelation time is several times shorter.
- ``"demcz"``, differential evolution from an archive of past states (ter Braak
  & Vrugt 2008): every walker moves by ``s (z_a - z_b)``, two distinct points
  of an archive ``Z``, with ``s = gamma (1 + lambda)``, ``lambda ~ U(-0.1,
  0.1)`` (a continuous scale, as in Vrugt et al.'s DREAM, 2009, so that jumps
  drawn from a finite archive reach every point), and ``s = 1`` one proposal
  in ten. Given the archive a walker's proposal depends on nothing but its
  own position and is symmetric (``(a, b)`` and ``(b, a)`` are equally
  likely, ``s`` is drawn alike), so every step is, walker by walker, a
  Metropolis step that leaves the target invariant, and *all* walkers move at
  once: one call of ``log_prob`` per step for the whole ensemble, where the
  two-halves moves make two sequential calls of half the size. The archive
  starts as the walkers' start positions and gains every walker's position
  after each step (every ``1 + n // 10000``-th step once it holds ``n``
  points); at the end of the burn-in it drops the start and the burn-in's
  first half (points on the way in). It changes the proposal by a share
  ``n_walkers / n`` a step, which vanishes as the chain runs: an adaptive
  chain with diminishing adaptation (Roberts & Rosenthal 2007), whose
  archive of draws from about the target gives the differences of the
  target, so the proposal approaches the optimal Gaussian random walk
  (``2.38^2 / n_dim`` times the target's covariance) whatever the number of
  walkers, where the red/blue moves draw from the few differences of the
  other half's walkers. Per call of ``log_prob`` it decorrelates 2-4 times
  faster than ``"de"`` on near-Gaussian targets of a few parameters
  (tests/test_sampler.py). It needs a burn-in that reaches the target's
  bulk: the points of its second half stay in the archive.

The moves only move along differences of walkers, so the start must span every
direction: a coordinate in which every walker starts at the same value would never
move, and such a start is refused (ter Braak's DE-MC adds a small random term
instead; the walkers' spread here is the proposal's only scale).

Randomness and resuming
-----------------------
The random numbers of sampler step ``k`` (0-based, counted from the start of
the chain) come from ``default_rng(SeedSequence(entropy, spawn_key=(*key,
STEP_TAG, k)))``, where ``entropy`` and ``key`` identify the chain. The final
`ChainState` stores positions, log-probabilities, the step counter, the
seed identity and the ``"demcz"`` archive as plain arrays and integers.
Sampling on from a stored state therefore reproduces, bit for bit, the walker trajectories of one
uninterrupted run with the same seed, provided the log-probability function
returns the same values (same model, data and options): a stored state's walkers
are rescored on resuming, and their stored values are kept where the function gives
them again, else replaced by the new ones. The *kept* samples of
the two pieces concatenate to those of the long run when the first piece's
``n_steps - burn_in`` is a multiple of ``thin`` and the second uses
``burn_in=0``.

Diagnostics
-----------
`split_r_hat` (Gelman & Rubin, with each chain split in halves),
`autocorrelation_time` (integrated, with Sokal's adaptive window, the
normalised autocovariance averaged over chains about their common mean) and
`effective_sample_size` (draws divided by that autocorrelation time).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import FrozenState, fmt, frozen_array, markdown_table
from ..errors import AeroidError, InferenceError
from ..io.data import as_float

__all__ = [
    "ChainState",
    "SamplerRun",
    "autocorrelation_time",
    "effective_sample_size",
    "ensemble_sampler",
    "seed_sequence",
    "split_r_hat",
]

FloatArray = NDArray[np.float64]
LogProb = Callable[[FloatArray], ArrayLike]

# Domain tags in the spawn key keep the sampler's streams apart from any other
# stream derived from the same seed specification.
STEP_TAG = 0x5354_4550  # "STEP"
INIT_TAG = 0x494E_4954  # "INIT"


def seed_sequence(seed: int | np.random.SeedSequence | None) -> np.random.SeedSequence:
    """Normalise a seed specification to a `SeedSequence` with an integer entropy.

    ``None`` draws fresh entropy from the operating system; the result records
    it, so the run can still be repeated.
    """
    if isinstance(seed, np.random.SeedSequence):
        ss = seed
    elif seed is None:
        ss = np.random.SeedSequence()
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0:
        ss = np.random.SeedSequence(int(seed))
    else:
        raise InferenceError(
            f"seed: expected a non-negative integer, a numpy SeedSequence or None, got {seed!r}"
        )
    if not isinstance(ss.entropy, (int, np.integer)):
        raise InferenceError(
            "seed: a SeedSequence with a sequence as entropy cannot be stored; "
            "build it from a single non-negative integer"
        )
    return ss


def _identity(ss: np.random.SeedSequence) -> tuple[int, tuple[int, ...]]:
    """Entropy and spawn key of a sequence built by `seed_sequence`."""
    return int(ss.entropy), tuple(int(k) for k in ss.spawn_key)  # type: ignore[arg-type]


def _stream(entropy: int, key: tuple[int, ...], *tail: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=(*key, *tail)))


@dataclass(frozen=True, eq=False)
class ChainState(FrozenState):
    """Where an ensemble stands: enough to continue sampling exactly.

    Attributes
    ----------
    positions : ndarray, shape (n_walkers, n_dim)
        Walker positions after the last step.
    log_prob : ndarray, shape (n_walkers,)
        Their log-probabilities (``-inf`` for a walker that never found a
        valid point).
    step : int
        Number of sampler steps taken since the chain started.
    entropy : int
        Entropy of the chain's `SeedSequence`.
    spawn_key : tuple of int
        Spawn key of the chain's `SeedSequence`; step ``k`` draws from
        ``SeedSequence(entropy, spawn_key=(*spawn_key, STEP_TAG, k))``.
    archive : ndarray, shape (n_archive, n_dim)
        The ``"demcz"`` move's archive of past states (empty for the other moves).
    """

    positions: FloatArray
    log_prob: FloatArray
    step: int
    entropy: int
    spawn_key: tuple[int, ...]
    archive: FloatArray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "positions", frozen_array(np.atleast_2d(self.positions)))
        object.__setattr__(self, "log_prob", frozen_array(np.ravel(self.log_prob)))
        object.__setattr__(self, "step", int(self.step))
        object.__setattr__(self, "entropy", int(self.entropy))
        object.__setattr__(self, "spawn_key", tuple(int(k) for k in self.spawn_key))
        n_dim = self.positions.shape[1]
        archive = np.zeros((0, n_dim)) if self.archive is None else np.asarray(self.archive)
        if archive.size and (archive.ndim != 2 or archive.shape[1] != n_dim):
            raise InferenceError(
                f"ChainState: archive of shape {archive.shape} for {n_dim} parameters; "
                f"expected (n_archive, {n_dim})"
            )
        archive = np.asarray(archive, dtype=np.float64).reshape(-1, n_dim)
        object.__setattr__(self, "archive", frozen_array(archive))
        if self.positions.shape[0] != self.log_prob.shape[0]:
            raise InferenceError(
                f"ChainState: {self.positions.shape[0]} positions but "
                f"{self.log_prob.shape[0]} log-probabilities"
            )

    @property
    def seed(self) -> np.random.SeedSequence:
        """The chain's `SeedSequence`."""
        return np.random.SeedSequence(self.entropy, spawn_key=self.spawn_key)


@dataclass(frozen=True, eq=False)
class SamplerRun(FrozenState):
    """Output of `ensemble_sampler`.

    Attributes
    ----------
    chain : ndarray, shape (n_kept, n_walkers, n_dim)
        Kept walker positions, after burn-in and thinning.
    log_prob : ndarray, shape (n_kept, n_walkers)
        Their log-probabilities.
    accepted : ndarray, shape (n_walkers,)
        Accepted proposals per walker over all `n_steps` steps.
    n_steps, burn_in, thin : int
        Steps taken in this run; the first `burn_in` were discarded and every
        `thin`-th of the rest kept.
    stretch : float
        Stretch-move scale ``a``.
    state : ChainState
        Final state, for resuming.
    move : str
        ``"stretch"``, ``"de"`` or ``"demcz"``.
    """

    chain: FloatArray
    log_prob: FloatArray
    accepted: FloatArray
    n_steps: int
    burn_in: int
    thin: int
    stretch: float
    state: ChainState
    move: str = "stretch"

    def __post_init__(self) -> None:
        for name in ("chain", "log_prob", "accepted"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        for name in ("n_steps", "burn_in", "thin"):
            object.__setattr__(self, name, int(getattr(self, name)))
        object.__setattr__(self, "stretch", float(self.stretch))

    @property
    def acceptance_fraction(self) -> FloatArray:
        """Fraction of accepted proposals per walker."""
        out = self.accepted / max(self.n_steps, 1)
        out.setflags(write=False)
        return out

    def summary(self) -> str:
        """Markdown: per dimension the draws' mean, standard deviation, 95 % interval,
        split R-hat and effective sample size, then the run's settings."""
        names = [f"x[{j}]" for j in range(self.chain.shape[2])]
        return _chain_table(self.chain, names) + "\n\n" + _run_line(self)

    def plot(self, **kwargs: Any) -> Any:
        """Walker traces, one panel a dimension. Returns a matplotlib Figure."""
        from ..reports.chain_plots import plot_chain

        return plot_chain(self.chain, [f"x[{j}]" for j in range(self.chain.shape[2])], **kwargs)


def _chain_table(chain: FloatArray, names: list[str]) -> str:
    """A sampler chain's per-parameter statistics as a Markdown table."""
    draws = chain.reshape(-1, chain.shape[2])
    lo, med, hi = np.percentile(draws, (2.5, 50.0, 97.5), axis=0)
    # the diagnostics need a few steps (R-hat four, ESS two); a shorter chain has none
    undefined = np.full(len(names), np.nan)
    r_hat = np.atleast_1d(split_r_hat(chain)) if chain.shape[0] >= 4 else undefined
    ess = np.atleast_1d(effective_sample_size(chain)) if chain.shape[0] >= 2 else undefined
    rows = [
        (
            n,
            fmt(float(draws[:, j].mean())),
            fmt(float(draws[:, j].std(ddof=1)) if draws.shape[0] > 1 else float("nan")),
            fmt(float(lo[j])),
            fmt(float(med[j])),
            fmt(float(hi[j])),
            f"{r_hat[j]:.3f}" if math.isfinite(r_hat[j]) else "—",
            f"{ess[j]:.0f}" if math.isfinite(ess[j]) else "—",
        )
        for j, n in enumerate(names)
    ]
    return markdown_table(
        ("parameter", "mean", "std. dev.", "P2.5", "P50", "P97.5", "R-hat", "ESS"), rows
    )


def _run_line(run: SamplerRun) -> str:
    """What a run kept and how it moved, in one sentence."""
    n_kept, walkers = run.chain.shape[:2]
    return (
        f"{n_kept * walkers} draws: {walkers} walkers × {n_kept} kept steps ({run.n_steps} "
        f"steps, {run.burn_in} burn-in, thin {run.thin}; {run.move} move); acceptance "
        f"fraction {float(np.mean(run.acceptance_fraction)):.2f}."
    )


def _score(log_prob: LogProb, theta: FloatArray) -> FloatArray:
    """Call the user's log-probability on a batch; NaN and +-inf become -inf."""
    try:
        raw = log_prob(theta)
        out = np.asarray(raw, dtype=np.float64)
    except AeroidError:
        raise
    except Exception as exc:  # the user's function: named, with what it was given
        raise InferenceError(
            f"log_prob raised {type(exc).__name__} on a batch of {theta.shape[0]} points: {exc}"
        ) from exc
    if out.shape != (theta.shape[0],):
        if out.size == theta.shape[0]:
            out = out.reshape(theta.shape[0])
        else:
            raise InferenceError(
                f"log_prob returned shape {np.shape(raw)} for a batch of {theta.shape[0]} "
                f"points; expected ({theta.shape[0]},)"
            )
    return np.where(np.isfinite(out), out, -np.inf)


MOVES = ("stretch", "de", "demcz")
# most points the "demcz" archive holds: its burn-in appends every k-th step's walkers
_ARCHIVE_ROWS = 10_000
# share of "demcz" proposals with scale 1 (jumps between modes) and the half-width of the
# uniform relative spread of the others' scale
_JUMP_SHARE = 0.1
_SCALE_SPREAD = 0.1


def _check_int(name: str, value: Any, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InferenceError(f"{name}: expected an integer >= {lo}, got {value!r}")
    return int(value)


def check_walkers(n_walkers: int, n_dim: int) -> int:
    """Validate an ensemble size: even and at least ``2 * n_dim`` (and 4)."""
    n = _check_int("n_walkers", n_walkers, 1)
    need = max(4, 2 * n_dim)
    if n < need or n % 2:
        raise InferenceError(
            f"n_walkers: the ensemble moves (split in two halves) need an even number of walkers, at least "
            f"max(4, 2 * n_dim) = {need} for {n_dim} parameters; got {n_walkers!r}"
        )
    return n


def ensemble_sampler(
    log_prob: LogProb,
    start: ArrayLike | ChainState,
    n_steps: int,
    *,
    seed: int | np.random.SeedSequence | None = None,
    stretch: float = 2.0,
    burn_in: int = 0,
    thin: int = 1,
    progress: bool = False,
    move: str = "stretch",
) -> SamplerRun:
    """Sample with an affine-invariant ensemble move, one vectorised call per (half-)ensemble.

    Parameters
    ----------
    log_prob : callable
        ``log_prob(theta) -> (B,)`` for ``theta`` of shape (B, n_dim): the
        unnormalised log-density of a batch of points. NaN or infinite
        values reject the point.
    start : array_like, shape (n_walkers, n_dim), or ChainState
        Initial walker positions (scored with `log_prob` first), or the
        state a previous run ended in. The walkers must span every
        direction (no coordinate without spread, no walkers on a line or
        plane): the moves only move along differences of walkers. A state's
        walkers are rescored with `log_prob` (one call per half-ensemble):
        where `log_prob` gives their stored log-probabilities (to a relative
        1e-8) those are kept and, with ``seed=None``, the run continues that
        chain exactly; another function (more data, a corrected likelihood)
        continues from the same positions under the new one.
    n_steps : int
        Number of ensemble steps (each moves every walker once).
    seed : int or SeedSequence, optional
        Seed of the random stream. When `start` is a `ChainState`, None
        continues its stream and a seed starts a fresh one.
    stretch : float
        Scale ``a > 1`` of the stretch distribution ``g(z) ∝ 1/sqrt(z)`` on
        ``[1/a, a]``.
    burn_in : int
        Leading steps discarded from the returned chain.
    thin : int
        Keep every `thin`-th step after burn-in.
    progress : bool
        Show a tqdm progress bar (if tqdm is installed).
    move : {"stretch", "de", "demcz"}
        The stretch move, differential evolution between the walkers of the
        other half, or differential evolution from an archive of past states
        (one call per step for all walkers; see the module notes).

    Returns
    -------
    SamplerRun

    Raises
    ------
    InferenceError
        Invalid arguments, walkers that do not span every direction (the
        message names the coordinates without spread), or no walker with a
        finite log-probability at the start.
    """
    return _sample(
        log_prob,
        start,
        n_steps,
        seed=seed,
        stretch=stretch,
        burn_in=burn_in,
        thin=thin,
        progress=progress,
        move=move,
        rescore=True,
    )


def _sample(
    log_prob: LogProb,
    start: ArrayLike | ChainState,
    n_steps: int,
    *,
    seed: int | np.random.SeedSequence | None,
    stretch: float,
    burn_in: int,
    thin: int,
    progress: bool,
    move: str,
    rescore: bool,
) -> SamplerRun:
    """`ensemble_sampler`; ``rescore=False`` takes a state's log-probabilities as they
    are, for a caller that has just computed or checked them with this `log_prob`."""
    n_steps = _check_int("n_steps", n_steps, 1)
    burn_in = _check_int("burn_in", burn_in, 0)
    thin = _check_int("thin", thin, 1)
    if burn_in >= n_steps:
        raise InferenceError(f"burn_in ({burn_in}) must be smaller than n_steps ({n_steps})")
    a = as_float(stretch)
    if a is None:
        raise InferenceError(f"stretch: expected a number > 1, got {stretch!r}")
    if not (a > 1.0 and math.isfinite(a)):
        raise InferenceError(f"stretch: expected a finite number > 1, got {stretch!r}")
    if move not in MOVES:
        raise InferenceError(f"move: expected one of {list(MOVES)}, got {move!r}")

    stored: FloatArray | None = None
    archive: FloatArray | None = None
    if isinstance(start, ChainState):
        x = np.array(start.positions, dtype=np.float64)
        stored = np.array(start.log_prob, dtype=np.float64)
        if start.archive is not None and start.archive.shape[0] >= 2:
            archive = np.array(start.archive, dtype=np.float64)
        if seed is None:
            entropy, key, step0 = start.entropy, start.spawn_key, start.step
        else:
            entropy, key = _identity(seed_sequence(seed))
            step0 = 0
    else:
        x = np.array(start, dtype=np.float64)
        if x.ndim != 2:
            raise InferenceError(
                f"start: expected walker positions of shape (n_walkers, n_dim), got {x.shape}"
            )
        if not np.all(np.isfinite(x)):
            raise InferenceError("start: walker positions contain NaN or infinite values")
        entropy, key = _identity(seed_sequence(seed))
        step0 = 0
    n_walkers, n_dim = x.shape
    check_walkers(n_walkers, n_dim)
    _check_spread(x)
    half = n_walkers // 2
    if stored is not None and not rescore:
        lp = stored
    else:
        # scored in the batches the moves score (halves, or all walkers for "demcz")
        if move == "demcz":
            lp = _score(log_prob, x)
        else:
            lp = np.concatenate([_score(log_prob, x[:half]), _score(log_prob, x[half:])])
        if stored is not None and _same_scores(lp, stored):
            # the function still gives the stored values: keep them bit for bit, so that
            # the continuation equals one uninterrupted run; else the rescored values hold
            lp = stored
    if not np.any(np.isfinite(lp)):
        raise InferenceError(
            "no walker starts at a point with finite log-probability (every start point "
            "is outside the prior support or fails to evaluate)"
        )

    n_kept = (n_steps - burn_in) // thin
    chain = np.empty((n_kept, n_walkers, n_dim))
    chain_lp = np.empty((n_kept, n_walkers))
    accepted = np.zeros(n_walkers)
    halves = ((slice(0, half), slice(half, None)), (slice(half, None), slice(0, half)))
    log_a = math.log(a)
    gamma = 2.38 / math.sqrt(2.0 * n_dim)
    grow = _Archive(x if archive is None else archive, burn_in)
    bar = _progress(n_steps) if progress else None
    try:
        for k in range(n_steps):
            rng = _stream(entropy, key, STEP_TAG, step0 + k)
            if move == "demcz":
                _demcz_step(log_prob, rng, x, lp, accepted, grow.rows(), gamma)
                grow.add(k, step0 + k, x)
            # the two halves in turn (none for "demcz", which moved every walker above)
            for act, comp in halves if move != "demcz" else ():
                xs = x[act]
                xc = x[comp]
                if move == "stretch":
                    # z = ((a - 1) u + 1)^2 / a has density ∝ 1/sqrt(z) on [1/a, a]
                    z = np.exp(2.0 * np.log1p((a - 1.0) * rng.random(half)) - log_a)
                    partner = xc[rng.integers(0, xc.shape[0], half)]
                    proposal = partner + z[:, None] * (xs - partner)
                    jacobian = (n_dim - 1.0) * np.log(z)
                else:
                    # two distinct partners; (i, j) and (j, i) are equally likely, so the
                    # proposal is symmetric and the ratio is that of the densities
                    m = xc.shape[0]
                    i = rng.integers(0, m, half)
                    j = (i + 1 + rng.integers(0, m - 1, half)) % m
                    g = np.where(rng.random(half) < 0.1, 1.0, gamma)
                    proposal = xs + g[:, None] * (xc[i] - xc[j])
                    jacobian = np.zeros(half)
                lp_new = _score(log_prob, proposal)
                with np.errstate(invalid="ignore"):
                    log_ratio = jacobian + lp_new - lp[act]
                    ok = np.log(rng.random(half)) < log_ratio
                idx = np.flatnonzero(ok) + (0 if act.start == 0 else half)
                x[idx] = proposal[ok]
                lp[idx] = lp_new[ok]
                accepted[idx] += 1
            done = k + 1
            if done > burn_in and (done - burn_in) % thin == 0:
                j = (done - burn_in) // thin - 1
                chain[j] = x
                chain_lp[j] = lp
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    kept_archive = grow.rows() if move == "demcz" else None
    state = ChainState(x, lp, step0 + n_steps, entropy, key, kept_archive)
    return SamplerRun(chain, chain_lp, accepted, n_steps, burn_in, thin, a, state, move)


def _same_scores(fresh: FloatArray, stored: FloatArray) -> bool:
    """Whether rescored log-probabilities are the stored ones (to rounding; a batch of
    another composition may round differently)."""
    both_out = np.isneginf(fresh) & np.isneginf(stored)
    return bool(np.all(np.isclose(fresh, stored, rtol=1e-8, atol=1e-8) | both_out))


# Walkers whose spread, each coordinate scaled to unit spread, has a singular value below
# this fraction of the largest lie on a subspace (to rounding).
_FLAT_SPREAD = 1e-10


def _check_spread(x: FloatArray) -> None:
    """Refuse walkers that do not span every direction: the stretch and
    differential-evolution moves only move along differences of walkers, so a
    direction without spread would never be explored (emcee refuses such starts)."""
    dev = x - x.mean(axis=0)
    scale = np.sqrt(np.mean(dev**2, axis=0))
    flat = np.flatnonzero(~(scale > 0.0))
    if flat.size:
        raise InferenceError(
            f"start: the walkers have no spread in coordinate(s) {flat.tolist()} (0-based); "
            "the ensemble moves only move along differences of walkers and would never "
            "explore them: start from a ball of distinct points"
        )
    _, sv, vt = np.linalg.svd(dev / scale, full_matrices=False)
    if sv[-1] < _FLAT_SPREAD * sv[0]:
        null = np.abs(vt[-1])
        tied = np.flatnonzero(null > 0.1 * null.max()).tolist()
        raise InferenceError(
            f"start: the walkers lie on a subspace: coordinates {tied} (0-based) are "
            "linearly dependent across the walkers, and the ensemble moves would never "
            "leave that subspace: start from a ball of points in general position"
        )


class _Archive:
    """The "demcz" archive: the points given, then the walkers' positions after each
    step, every ``1 + n // _ARCHIVE_ROWS``-th step once it holds ``n`` points (a
    rule of the state alone, so that a resumed chain grows it as one long run would);
    at the end of the burn-in only the points of its second half are kept."""

    def __init__(self, first: FloatArray, burn_in: int) -> None:
        self.z = np.array(first, dtype=np.float64)
        self.start = 0
        self.n = first.shape[0]
        self.burn_in = burn_in
        self.half = 0

    def rows(self) -> FloatArray:
        return self.z[self.start : self.n]

    def add(self, k: int, step: int, x: FloatArray) -> None:
        """After local step `k` (global `step`), with the walkers at `x`."""
        if k == self.burn_in // 2 and self.burn_in >= 2:
            self.half = self.n
        if (step + 1) % (1 + (self.n - self.start) // _ARCHIVE_ROWS) == 0:
            if self.n + x.shape[0] > self.z.shape[0]:
                grown = np.empty((2 * self.z.shape[0] + x.shape[0], x.shape[1]))
                grown[: self.n] = self.z[: self.n]
                self.z = grown
            self.z[self.n : self.n + x.shape[0]] = x
            self.n += x.shape[0]
        if k + 1 == self.burn_in and self.burn_in >= 2 and self.n - self.half >= 2:
            # the points given and the burn-in's first half may lie on the way in
            self.start = self.half


def _demcz_step(
    log_prob: LogProb,
    rng: np.random.Generator,
    x: FloatArray,
    lp: FloatArray,
    accepted: FloatArray,
    archive: FloatArray,
    gamma: float,
) -> None:
    """One "demcz" step: every walker proposes from archive differences, one call."""
    n = x.shape[0]
    m = archive.shape[0]
    # two distinct archive points; (a, b) and (b, a) are equally likely
    i = rng.integers(0, m, n)
    j = (i + 1 + rng.integers(0, m - 1, n)) % m
    jump = rng.random(n) < _JUMP_SHARE
    spread = 1.0 + _SCALE_SPREAD * (2.0 * rng.random(n) - 1.0)
    s = np.where(jump, 1.0, gamma * spread)
    proposal = x + s[:, None] * (archive[i] - archive[j])
    lp_new = _score(log_prob, proposal)
    with np.errstate(invalid="ignore"):
        ok = np.log(rng.random(n)) < lp_new - lp
    x[ok] = proposal[ok]
    lp[ok] = lp_new[ok]
    accepted[ok] += 1


def _progress(total: int) -> Any:
    from .._progress import progress_bar

    return progress_bar(total, desc="ensemble sampler", unit="step")


# -- diagnostics ----------------------------------------------------------------------------


def _as_chains(x: ArrayLike, name: str, min_steps: int) -> tuple[FloatArray, bool]:
    """Shape (n_steps, n_chains, n_dim); the flag says whether the input had a dim axis."""
    if np.iscomplexobj(x):  # a cast would drop the imaginary part
        raise InferenceError(f"{name}: complex samples are not supported")
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InferenceError(
            f"{name}: expected an array of numbers, got {type(x).__name__}"
        ) from None
    if a.ndim == 1:
        a = a[:, None, None]
        vector = False
    elif a.ndim == 2:
        a = a[:, :, None]
        vector = False
    elif a.ndim == 3:
        vector = True
    else:
        raise InferenceError(
            f"{name}: expected samples of shape (n_steps,), (n_steps, n_chains) or "
            f"(n_steps, n_chains, n_dim), got {a.shape}"
        )
    if a.shape[0] < min_steps or a.shape[1] < 1:
        raise InferenceError(
            f"{name}: needs at least {min_steps} steps and one chain, got shape {np.shape(x)}"
        )
    if not np.all(np.isfinite(a)):
        raise InferenceError(f"{name}: samples contain NaN or infinite values")
    return a, vector


def split_r_hat(samples: ArrayLike) -> Any:
    """Split-R-hat (Gelman–Rubin potential scale reduction) of chains.

    Parameters
    ----------
    samples : array_like
        Shape (n_steps, n_chains) or (n_steps, n_chains, n_dim); each chain is
        split into its first and second half (a middle step is dropped for
        odd lengths) and the halves are compared as separate chains.

    Returns
    -------
    float or ndarray of shape (n_dim,)
        ``sqrt(var⁺ / W)`` with ``W`` the mean within-chain variance and
        ``var⁺ = (n-1)/n W + B/n``; values near 1 indicate that the chains
        agree. ``inf`` when the chains are constant but different, NaN when
        all samples are equal.
    """
    a, vector = _as_chains(samples, "split_r_hat", 4)
    n = a.shape[0] // 2
    halves = np.concatenate([a[:n], a[a.shape[0] - n :]], axis=1)  # (n, 2m, d)
    w = halves.var(axis=0, ddof=1).mean(axis=0)
    b_over_n = halves.mean(axis=0).var(axis=0, ddof=1)
    var_plus = (n - 1) / n * w + b_over_n
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.sqrt(var_plus / w)
    r = np.where((w == 0) & (b_over_n > 0), np.inf, r)
    return r if vector else float(r[0])


def _autocovariance(a: FloatArray) -> FloatArray:
    """Autocovariance about the common mean, averaged over chains: shape (n_steps, n_dim)."""
    n = a.shape[0]
    centred = a - a.mean(axis=(0, 1), keepdims=True)
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(centred, n=nfft, axis=0)
    acov = np.fft.irfft(f * np.conj(f), n=nfft, axis=0)[:n] / n
    return np.asarray(acov.mean(axis=1))


def autocorrelation_time(samples: ArrayLike, *, c: float = 5.0) -> Any:
    """Integrated autocorrelation time with Sokal's adaptive window.

    The normalised autocovariance ``rho(t)`` is averaged over chains (taken
    about their common mean, so disagreement between chains lengthens the
    estimate), ``tau(M) = 1 + 2 sum_{t=1..M} rho(t)`` and the window is the
    smallest ``M >= c tau(M)``. When no such window exists the chain is too
    short to estimate ``tau``; the value at the longest lag is returned, which
    then underestimates it (see the ``50 tau`` rule in `aeroid.infer`).

    Parameters
    ----------
    samples : array_like
        Shape (n_steps,), (n_steps, n_chains) or (n_steps, n_chains, n_dim).
    c : float
        Window constant (Sokal recommends about 5).

    Returns
    -------
    float or ndarray of shape (n_dim,)
        ``tau`` in steps (``inf`` for a constant chain).
    """
    a, vector = _as_chains(samples, "autocorrelation_time", 2)
    value = as_float(c)
    if value is None or not (value > 0 and math.isfinite(value)):
        raise InferenceError(f"c: expected a positive window constant, got {c!r}")
    c = value
    acov = _autocovariance(a)
    out = np.empty(a.shape[2])
    for d in range(a.shape[2]):
        if acov[0, d] <= 0.0:
            out[d] = np.inf
            continue
        taus = 2.0 * np.cumsum(acov[:, d] / acov[0, d]) - 1.0
        ok = np.arange(taus.size) >= c * taus
        m = int(np.argmax(ok)) if np.any(ok) else taus.size - 1
        out[d] = taus[m]
    return out if vector else float(out[0])


def effective_sample_size(samples: ArrayLike, *, c: float = 5.0) -> Any:
    """Effective number of independent draws: total draws over `autocorrelation_time`.

    Same shapes as `autocorrelation_time`; capped at the number of draws.
    """
    a, vector = _as_chains(samples, "effective_sample_size", 2)
    tau = np.atleast_1d(autocorrelation_time(a, c=c))
    total = a.shape[0] * a.shape[1]
    ess = np.where(np.isfinite(tau), total / np.maximum(tau, 1.0), 0.0)
    return ess if vector else float(ess[0])
