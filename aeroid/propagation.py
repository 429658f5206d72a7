"""Monte Carlo propagation of parameter uncertainty into engineering quantities."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._records import fmt, frozen_array, markdown_table
from .data import plain, whole_number
from .errors import AeroidError

__all__ = [
    "BLOCK_SIZE",
    "PropagationBatch",
    "PropagationResult",
    "combine_batches",
    "draw_parameters",
    "propagate",
    "propagate_batch",
]

FloatArray = NDArray[np.float64]

#: Draws are generated in blocks of this size, block b from
#: ``SeedSequence(seed, spawn_key=(b,))``, so the samples do not depend on how
#: a caller (such as the pipeline) splits the work into batches.
BLOCK_SIZE = 256


class PropagationError(AeroidError, ValueError):
    """Propagation cannot run (no usable draws, bad arguments)."""


@dataclass(frozen=True, eq=False)
class PropagationResult:
    """Distribution of a metric under parameter uncertainty.

    Attributes
    ----------
    mean, std : float
    percentiles : mapping of str to float
        Keys like ``"P2.5"``.
    samples : ndarray
        Metric values of the successful draws.
    n_samples : int
        Draws attempted.
    n_failed : int
        Draws where the metric raised or returned a non-finite value.
    seed : int or None
    source : str
        ``"covariance"`` (Gaussian draws) or ``"posterior"`` (resampled rows).
    """

    mean: float
    std: float
    percentiles: Mapping[str, float]
    samples: FloatArray
    n_samples: int
    n_failed: int
    seed: int | None
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "percentiles", MappingProxyType(dict(self.percentiles)))
        object.__setattr__(self, "samples", frozen_array(self.samples))

    def plot(self, **kwargs: Any) -> Any:
        """Histogram of the propagated metric. Returns a matplotlib Figure."""
        from .plotting import plot_propagation

        return plot_propagation(self, **kwargs)

    def summary(self) -> str:
        """Markdown table of the metric's statistics."""
        rows = [("mean", fmt(self.mean)), ("std", fmt(self.std))]
        rows += [(k, fmt(v)) for k, v in self.percentiles.items()]
        text = markdown_table(("statistic", "value"), rows)
        note = f"{self.n_samples - self.n_failed} of {self.n_samples} draws ({self.source})"
        if self.n_failed:
            note += f"; {self.n_failed} failed and are excluded"
        return text + "\n\n" + note + "."


def _source(result: Any) -> tuple[list[str], FloatArray, FloatArray | None, dict[str, float]]:
    names = list(getattr(result, "parameter_names", ()))
    fixed = {k: float(v) for k, v in dict(getattr(result, "fixed", {}) or {}).items()}
    samples = getattr(result, "samples", None)
    if samples is not None and np.ndim(samples) == 2:
        arr = np.asarray(samples, dtype=np.float64)
        if arr.shape[1] != len(names):
            raise PropagationError("posterior samples do not match parameter_names")
        return names, arr, None, fixed
    if not names or not hasattr(result, "covariance"):
        raise PropagationError(
            "propagate needs an identification result (parameters + covariance) or a "
            f"posterior (samples), got {type(result).__name__}"
        )
    mean = np.array([float(result.parameters[n]) for n in names])
    cov = np.asarray(result.covariance, dtype=np.float64)
    if not np.all(np.isfinite(cov)):
        raise PropagationError(
            "the covariance holds non-finite entries (unidentifiable parameters); "
            "fix or drop those parameters before propagating"
        )
    return names, mean, cov, fixed


def draw_parameters(result: Any, n_samples: int, seed: int | None, start: int = 0) -> FloatArray:
    """Parameter draws ``start .. start + n_samples`` of the stream for `seed`.

    Block-wise generation makes any split of the index range reproduce the
    same rows as one call.
    """
    names, first, cov, _ = _source(result)
    stop = start + n_samples
    out = np.empty((n_samples, len(names)))
    if cov is not None:
        # Factor once; eigh tolerates positive semidefinite covariances.
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        root = v * np.sqrt(np.clip(w, 0, None))
    for block in range(start // BLOCK_SIZE, (stop - 1) // BLOCK_SIZE + 1):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(block,)))
        lo = block * BLOCK_SIZE
        if cov is None:
            rows = first[rng.integers(0, first.shape[0], BLOCK_SIZE)]
        else:
            rows = first + rng.standard_normal((BLOCK_SIZE, len(names))) @ root.T
        a, b = max(start, lo), min(stop, lo + BLOCK_SIZE)
        out[a - start : b - start] = rows[a - lo : b - lo]
    return out


@dataclass(frozen=True, eq=False)
class PropagationBatch:
    """The metric at draws ``start .. start + len(values)`` of one seed's stream.

    Batches of one seed computed anywhere (other processes, other machines)
    combine with `combine_batches` into exactly the result of `propagate`.

    Attributes
    ----------
    start : int
        Index of the batch's first draw in the stream.
    values : ndarray
        Metric value of each draw; NaN where the metric raised or returned a
        non-finite value.
    seed : int
    source : str
        ``"covariance"`` or ``"posterior"``, as in `PropagationResult`.
    """

    start: int
    values: FloatArray
    seed: int
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", int(self.start))
        object.__setattr__(self, "values", frozen_array(self.values))

    @property
    def stop(self) -> int:
        """Index one past the batch's last draw."""
        return self.start + int(self.values.shape[0])

    def summary(self) -> str:
        """One line: which draws, how many failed."""
        failed = int(np.sum(~np.isfinite(self.values)))
        return (
            f"draws {self.start}-{self.stop} of seed {self.seed} ({self.source}), {failed} failed"
        )


def _check_seed(seed: Any) -> int:
    if seed is None:
        return int(np.random.SeedSequence().generate_state(1)[0])
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise PropagationError(f"seed must be a non-negative integer or None, got {plain(seed)}")
    return int(seed)


def propagate_batch(
    result: Any,
    func: Callable[[dict[str, float]], float],
    *,
    start: int,
    n_samples: int,
    seed: int,
    progress: bool = False,
) -> PropagationBatch:
    """Evaluate a metric at one batch of the draws that `propagate` makes.

    Parameters
    ----------
    result : IdentificationResult or InferenceResult
        As in `propagate`.
    func : callable
        ``func(parameters: dict) -> float``.
    start : int
        Index of the batch's first draw in the stream of `seed`.
    n_samples : int
        Draws in the batch (0 allowed).
    seed : int
        Seed of the whole stream, shared by every batch of one propagation.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).

    Returns
    -------
    PropagationBatch
    """
    start = whole_number(start, "start", PropagationError, least=0)
    n_samples = whole_number(n_samples, "n_samples", PropagationError, least=0)
    if not callable(func):
        raise PropagationError("func must be callable: func(parameters: dict) -> float")
    seed = _check_seed(seed)
    names, _, cov, fixed = _source(result)
    draws = draw_parameters(result, n_samples, seed, start)
    values = np.full(draws.shape[0], np.nan)
    from ._progress import progress_bar

    bar = progress_bar(draws.shape[0], desc="propagate", enabled=progress, unit="draw")
    for i, row in enumerate(draws):
        if bar is not None:
            bar.update(1)
        p = dict(fixed)
        p.update(zip(names, row.tolist(), strict=True))
        try:
            v = float(func(p))  # a non-scalar raises and counts as a failure
        except Exception:  # a metric failing for some draws is expected, not fatal
            continue
        if np.isfinite(v):
            values[i] = v
    if bar is not None:
        bar.close()
    return PropagationBatch(
        start=start,
        values=values,
        seed=seed,
        source="covariance" if cov is not None else "posterior",
    )


def _percentiles(percentiles: Sequence[float]) -> list[float]:
    # A string is iterable: "50" would read as the percentiles 5 and 0.
    if isinstance(percentiles, (str, bytes)):
        raise PropagationError(
            f"percentiles must be a list of numbers in [0, 100], got the string {percentiles!r}"
        )
    try:
        pcts = [float(p) for p in percentiles]
    except (TypeError, ValueError):
        raise PropagationError(
            f"percentiles must be a list of numbers in [0, 100], got {plain(percentiles)}"
        ) from None
    if any(not 0.0 <= p <= 100.0 for p in pcts):
        shown = ", ".join(f"{p:g}" for p in pcts)
        raise PropagationError(f"percentiles must lie in [0, 100], got [{shown}]")
    return pcts


def combine_batches(
    batches: Sequence[PropagationBatch],
    *,
    percentiles: Sequence[float] = (2.5, 50.0, 97.5),
) -> PropagationResult:
    """Pool batches covering draws ``0 .. n`` of one seed into a `PropagationResult`.

    The result is the one `propagate` returns for ``n_samples=n`` and that
    seed, bit for bit, whatever the batches' sizes and order.

    Parameters
    ----------
    batches : sequence of PropagationBatch
        Together exactly the draws ``0 .. n``, each once, in any order.
    percentiles : sequence of float
        Percentiles to report (``"P2.5"`` etc.).
    """
    pcts = _percentiles(percentiles)
    if not batches:
        raise PropagationError("combine_batches needs at least one batch")
    first = batches[0]
    for b in batches:
        if b.seed != first.seed or b.source != first.source:
            raise PropagationError(
                "batches of different propagations cannot be combined "
                f"(seed {first.seed} from the {first.source}, seed {b.seed} from the {b.source})"
            )
    # an empty batch covers no draws, wherever it starts
    ordered = sorted((b for b in batches if b.values.size), key=lambda b: b.start)
    if not ordered:
        raise PropagationError("the batches hold no draws")
    at = 0
    for b in ordered:
        if b.start != at:
            what = "overlap" if b.start < at else "leave a gap"
            raise PropagationError(f"batches {what} at draw {min(at, b.start)}")
        at = b.stop
    values = np.concatenate([b.values for b in ordered])
    n_samples = int(values.shape[0])
    ok = np.isfinite(values)
    if not np.any(ok):
        raise PropagationError(f"the metric failed for all {n_samples} draws")
    good = values[ok]
    return PropagationResult(
        mean=float(good.mean()),
        std=float(good.std(ddof=1)) if good.size > 1 else 0.0,
        percentiles={f"P{p:g}": float(np.percentile(good, p)) for p in pcts},
        samples=good,
        n_samples=n_samples,
        n_failed=int((~ok).sum()),
        seed=first.seed,
        source=first.source,
    )


def propagate(
    result: Any,
    func: Callable[[dict[str, float]], float],
    *,
    n_samples: int = 1000,
    percentiles: Sequence[float] = (2.5, 50.0, 97.5),
    seed: int | None = None,
    progress: bool = False,
) -> PropagationResult:
    """Push parameter uncertainty through a metric by Monte Carlo.

    Parameters
    ----------
    result : IdentificationResult or InferenceResult
        Gaussian draws from an identification result's covariance, or rows
        resampled (with replacement) from a posterior's samples, so skew,
        bounds and correlations of the posterior are kept.
    func : callable
        ``func(parameters: dict) -> float``; gets fixed and drawn parameters.
    n_samples : int
        Number of draws.
    percentiles : sequence of float
        Percentiles to report (``"P2.5"`` etc.).
    seed : int, optional
        Seed of the draws; the same seed gives the same result. With None a
        fresh seed is drawn and recorded in the result.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).

    Returns
    -------
    PropagationResult
        Draws where `func` raises or returns a non-finite value are counted in
        ``n_failed``; they do not stop the run.

    See Also
    --------
    propagate_batch, combine_batches : the same draws split into batches that
        run anywhere (the pipeline's ``propagate: {n_batches: k}``).
    """
    n = whole_number(n_samples, "n_samples", PropagationError)
    pcts = _percentiles(percentiles)
    batch = propagate_batch(
        result, func, start=0, n_samples=n, seed=_check_seed(seed), progress=progress
    )
    return combine_batches([batch], percentiles=pcts)
