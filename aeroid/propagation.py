"""Monte Carlo propagation of parameter uncertainty into engineering quantities."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._records import fmt, frozen_array, markdown_table
from .errors import AeroidError

__all__ = ["BLOCK_SIZE", "PropagationResult", "draw_parameters", "propagate"]

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
    """
    if int(n_samples) < 1:
        raise PropagationError(f"n_samples must be a positive integer, got {n_samples!r}")
    if not callable(func):
        raise PropagationError("func must be callable: func(parameters: dict) -> float")
    pcts = [float(p) for p in percentiles]
    if any(not 0.0 <= p <= 100.0 for p in pcts):
        raise PropagationError(f"percentiles must lie in [0, 100], got {list(percentiles)}")
    if seed is None:
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    names, _, cov, fixed = _source(result)
    draws = draw_parameters(result, int(n_samples), seed)
    values = np.full(draws.shape[0], np.nan)
    from ._progress import progress_bar

    bar = progress_bar(draws.shape[0], desc="propagate", enabled=progress, unit="draw")
    for i, row in enumerate(draws):
        if bar is not None:
            bar.update(1)
        p = dict(fixed)
        p.update(zip(names, row.tolist(), strict=True))
        try:
            v = func(p)
            values[i] = float(v)  # a non-scalar raises and counts as a failure
        except Exception:  # a metric failing for some draws is expected, not fatal
            continue
    if bar is not None:
        bar.close()
    ok = np.isfinite(values)
    if not np.any(ok):
        raise PropagationError(f"the metric failed for all {n_samples} draws")
    good = values[ok]
    return PropagationResult(
        mean=float(good.mean()),
        std=float(good.std(ddof=1)) if good.size > 1 else 0.0,
        percentiles={f"P{p:g}": float(np.percentile(good, p)) for p in pcts},
        samples=good,
        n_samples=int(n_samples),
        n_failed=int((~ok).sum()),
        seed=seed,
        source="covariance" if cov is not None else "posterior",
    )
