"""Monte Carlo propagation of parameter uncertainty into engineering quantities."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, overload

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt, frozen_array, markdown_table
from .._threads import CALLER_STACKLEVEL, small_blas
from ..errors import PropagationError
from ..io.data import as_float, check_flag, plain, whole_number
from ._propagation_draws import BLOCK_SIZE, Source, draws, metric_identity, source

__all__ = [
    "BLOCK_SIZE",
    "PropagationBatch",
    "PropagationResult",
    "VectorPropagationResult",
    "combine_batches",
    "draw_parameters",
    "propagate",
    "propagate_batch",
]

FloatArray = NDArray[np.float64]

#: More failed draws than this fraction of all draws are reported by a warning.
FAILURE_WARNING_FRACTION = 0.01

# Most float64 values the draws or the metric's values of one batch may hold (1 GiB).
_MAX_VALUES = 2**27


@dataclass(frozen=True, eq=False)
class PropagationResult(FrozenState):
    """Distribution of a metric under parameter uncertainty.

    Attributes
    ----------
    mean : float
    std : float
        Sample standard deviation (ddof = 1); NaN when fewer than two draws succeeded.
    percentiles : mapping of str to float
        Keys like ``"P2.5"`` (deprecated shape, kept for one release: read
        `percentile_table`, the shape every result shares).
    samples : ndarray
        Metric values of the successful draws.
    n_samples : int
        Draws attempted.
    n_failed : int
        Draws where the metric raised or returned a non-finite value.
    seed : int or None
    source : str
        ``"covariance"`` (draws from the covariance, see `propagate`) or
        ``"posterior"`` (resampled rows).
    percentile_levels : tuple of float
        The levels asked for, in the order of `percentiles`.
    """

    mean: float
    std: float
    percentiles: Mapping[str, float]
    samples: FloatArray
    n_samples: int
    n_failed: int
    seed: int | None
    source: str
    percentile_levels: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "percentiles", MappingProxyType(dict(self.percentiles)))
        object.__setattr__(self, "samples", frozen_array(self.samples))
        object.__setattr__(self, "percentile_levels", tuple(map(float, self.percentile_levels)))

    @property
    def percentile_table(self) -> Mapping[str, Mapping[float, float]]:
        """The percentiles as every result gives them: name -> level (percent) -> value;
        the one name here is ``"metric"`` (``{"metric": {2.5: ..., 50.0: ..., 97.5: ...}}``),
        keyed by the levels asked for (``100 / 3``, not a rounded label)."""
        values = [float(v) for v in self.percentiles.values()]
        if len(self.percentile_levels) == len(values):
            levels = dict(zip(self.percentile_levels, values, strict=True))
        else:  # a record from before the levels were kept: read its labels
            levels = {float(k[1:]): float(v) for k, v in self.percentiles.items()}
        return MappingProxyType({"metric": MappingProxyType(levels)})

    def plot(self, **kwargs: Any) -> Any:
        """Histogram of the propagated metric. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_propagation

        return plot_propagation(self, **kwargs)

    def summary(self) -> str:
        """Markdown table of the metric's statistics."""
        rows = [("mean", fmt(self.mean)), ("std", fmt(self.std))]
        rows += [(f"P{p:g}", fmt(v)) for p, v in self.percentile_table["metric"].items()]
        text = markdown_table(("statistic", "value"), rows)
        note = f"{self.n_samples - self.n_failed} of {self.n_samples} draws ({self.source})"
        if self.n_failed:
            note += f"; {self.n_failed} failed and are excluded"
        return text + "\n\n" + note + "."


@dataclass(frozen=True, eq=False)
class VectorPropagationResult(FrozenState):
    """Distribution of a metric with several values: one `PropagationResult` per component.

    A metric returning a sequence or 1-D array gives components named
    ``"<metric>[0]"``, ``"<metric>[1]"``... (``<metric>`` is the function's
    name, ``metric`` for a lambda); one returning a mapping gives its keys.
    ``result["name"]`` is that component's `PropagationResult`.

    Attributes
    ----------
    components : mapping of str to PropagationResult
        In the metric's order. A component's ``n_failed`` counts the draws
        where the metric raised or that component was not finite.
    values : ndarray, shape (n_samples, n_components)
        Every draw's values, NaN where the draw failed (for the joint
        distribution of the components).
    n_samples : int
        Draws attempted.
    n_failed : int
        Draws where the metric raised, returned another shape, or returned a
        non-finite value in any component.
    seed : int or None
    source : str
        ``"covariance"`` or ``"posterior"``, as in `PropagationResult`.
    """

    components: Mapping[str, PropagationResult]
    values: FloatArray
    n_samples: int
    n_failed: int
    seed: int | None
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "components", MappingProxyType(dict(self.components)))
        object.__setattr__(self, "values", frozen_array(self.values))

    @property
    def names(self) -> tuple[str, ...]:
        """Component names, in the metric's order."""
        return tuple(self.components)

    def __getitem__(self, name: str) -> PropagationResult:
        try:
            return self.components[name]
        except KeyError:
            raise PropagationError(
                f"no component {name!r}; components: {list(self.components)}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.components

    @property
    def percentile_table(self) -> Mapping[str, Mapping[float, float]]:
        """The percentiles as every result gives them: component -> level (percent) -> value."""
        return MappingProxyType(
            {name: r.percentile_table["metric"] for name, r in self.components.items()}
        )

    def plot(self) -> Any:
        """Histograms of the components. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_vector_propagation

        return plot_vector_propagation(self)

    def summary(self) -> str:
        """Markdown table: one row per component."""
        table = self.percentile_table
        levels = list(next(iter(table.values())))
        rows = [
            (name, fmt(r.mean), fmt(r.std), *(fmt(table[name][p]) for p in levels))
            for name, r in self.components.items()
        ]
        keys = [f"P{p:g}" for p in levels]
        text = markdown_table(("component", "mean", "std", *keys), rows)
        good = self.n_samples - self.n_failed
        note = f"{good} of {self.n_samples} draws complete ({self.source})"
        if self.n_failed:
            note += f"; {self.n_failed} failed in some component and are excluded there"
        return text + "\n\n" + note + "."


def draw_parameters(result: Any, n_samples: int, seed: int | None, start: int = 0) -> FloatArray:
    """Parameter draws ``start .. start + n_samples`` of the stream for `seed`.

    Block-wise generation makes any split of the index range reproduce the
    same rows as one call. The rows are those `propagate` evaluates its metric at.
    """
    return draws(source(result), n_samples, seed, start)


@dataclass(frozen=True, eq=False)
class PropagationBatch(FrozenState):
    """The metric at draws ``start .. start + len(values)`` of one seed's stream.

    Batches of one seed computed anywhere (other processes, other machines)
    combine with `combine_batches` into exactly the result of `propagate`.

    Attributes
    ----------
    start : int
        Index of the batch's first draw in the stream.
    values : ndarray, shape (n,) or (n, n_components)
        Metric value of each draw; NaN where the metric raised or returned a
        non-finite value. Two-dimensional for a metric with several values
        (see `VectorPropagationResult`).
    seed : int
    source : str
        ``"covariance"`` or ``"posterior"``, as in `PropagationResult`.
    names : tuple of str
        Component names of a metric with several values; empty for a scalar
        metric (or when no draw of the stream up to the batch's end returned
        a value). A mapping's keys in the order of the first draw that
        returned one; a mapping with the same keys in another order is the
        same metric.
    first_error : str
        What the metric raised or returned at the batch's first failed draw.
    origin : str
        A digest of what the draws come from (parameters, covariance and
        degrees of freedom, or the posterior's rows): batches of different
        results do not combine.
    metric : str
        The metric's ``module.qualname#digest`` (its name and a hash of its
        code): batches of different metrics do not combine.
    """

    start: int
    values: FloatArray
    seed: int
    source: str
    names: tuple[str, ...] = ()
    first_error: str = ""
    origin: str = ""
    metric: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", int(self.start))
        object.__setattr__(self, "values", frozen_array(self.values))
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @property
    def stop(self) -> int:
        """Index one past the batch's last draw."""
        return self.start + int(self.values.shape[0])

    def summary(self) -> str:
        """One line: which draws, how many failed."""
        failed = int(np.sum(~_complete(self.values)))
        return (
            f"draws {self.start}-{self.stop} of seed {self.seed} ({self.source}), {failed} failed"
        )


def _check_seed(seed: Any) -> int:
    if seed is None:
        return int(np.random.SeedSequence().generate_state(1)[0])
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise PropagationError(f"seed must be a non-negative integer or None, got {plain(seed)}")
    return int(seed)


def _metric_name(func: Any) -> str:
    name = getattr(func, "__name__", "")
    return name if isinstance(name, str) and name.isidentifier() else "metric"


class _Shape:
    """What the metric returns, learnt from its first successful draw."""

    def __init__(self, func: Any) -> None:
        self.func_name = _metric_name(func)
        self.names: tuple[str, ...] | None = None  # None: not yet known; (): a scalar

    def convert(self, out: Any) -> float | FloatArray:
        """The draw's value(s), or ValueError naming what does not fit."""
        if type(out) is float:  # the common case, first
            got: tuple[str, ...] = ()
            value: float | FloatArray = out
        elif isinstance(out, Mapping):
            got = tuple(out)
            if not got or not all(isinstance(k, str) for k in got):
                raise ValueError(f"a mapping needs string keys, got {list(out)!r}")
            if self.names is not None and set(got) == set(self.names):
                got = self.names  # keyed by name: the same keys in another order, one metric
            value = np.array([float(out[k]) for k in got])
        else:
            if np.iscomplexobj(out):  # a cast would drop the imaginary part
                raise ValueError("complex values are not supported")
            arr = np.asarray(out, dtype=np.float64)
            if arr.ndim == 0:
                got, value = (), float(arr)
            elif arr.ndim == 1 and arr.size:
                got = tuple(f"{self.func_name}[{i}]" for i in range(arr.size))
                value = arr
            else:
                raise ValueError(f"expected a number or a 1-D sequence, got shape {arr.shape}")
        if self.names is None:
            self.names = got
        elif got != self.names:
            raise ValueError(
                f"returned {list(got) or 'a number'} after {list(self.names) or 'a number'}"
            )
        return value


def _complete(values: FloatArray) -> NDArray[np.bool_]:
    """Draws whose every value is finite."""
    ok = np.isfinite(values)
    return ok if ok.ndim == 1 else np.all(ok, axis=1)


def _learn_shape(shape: _Shape, src: Source, func: Any, stop: int, seed: int) -> None:
    """Teach `shape` the metric's shape as `propagate` learns it, from the first draw of
    the whole stream (before `stop`) where the metric returns a value it can read, so
    that every batch, wherever it starts, counts the same draws as of another shape."""
    for lo in range(0, stop, BLOCK_SIZE):
        for row in draws(src, min(BLOCK_SIZE, stop - lo), seed, lo).tolist():
            p = dict(src.fixed)
            p.update(zip(src.names, row, strict=True))
            try:
                shape.convert(func(p))
            except Exception:  # a failed draw teaches nothing, as in the batch itself
                continue
            return


def propagate_batch(
    result: Any,
    func: Callable[[dict[str, float]], Any],
    *,
    start: int,
    n_samples: int,
    seed: int,
    progress: bool = False,
) -> PropagationBatch:
    """Evaluate a metric at one batch of the draws that `propagate` makes.

    Parameters
    ----------
    result : IdentificationResult, InferenceResult or fit
        As in `propagate`.
    func : callable
        ``func(parameters: dict) -> float``, or a sequence or mapping of
        floats (see `propagate`).
    start : int
        Index of the batch's first draw in the stream of `seed`. The metric's
        shape (a number, or which components) is that of the first draw of
        the whole stream where it returns a value, as in `propagate`: a
        batch that starts later first evaluates the metric at draws 0, 1, ...
        until one returns (usually one extra evaluation).
    n_samples : int
        Draws in the batch (0 allowed).
    seed : int
        Seed of the whole stream, shared by every batch of one propagation.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).

    Returns
    -------
    PropagationBatch

    Raises
    ------
    PropagationError
        Bad arguments (among them a `progress` that is not a bool), or more
        draws than fit in memory.
    """
    start = whole_number(start, "start", PropagationError, least=0)
    n_samples = whole_number(n_samples, "n_samples", PropagationError, least=0)
    if not callable(func):
        raise PropagationError("func must be callable: func(parameters: dict) -> float")
    check_flag(progress, "progress", PropagationError)
    seed = _check_seed(seed)
    src = source(result)
    names, fixed = src.names, src.fixed
    if n_samples * max(len(names), 1) > _MAX_VALUES:  # all draws are made up front
        raise PropagationError(
            f"n_samples={n_samples}: {n_samples} draws of {len(names)} parameters would not "
            f"fit in memory (at most {_MAX_VALUES} values); split them with propagate_batch"
        )
    rows = draws(src, n_samples, seed, start)
    n = rows.shape[0]
    values = np.full(n, np.nan)
    shape = _Shape(func)
    if n and start:
        _learn_shape(shape, src, func, start, seed)
    first_error = ""
    from .._progress import progress_bar

    bar = progress_bar(n, desc="propagate", enabled=progress, unit="draw")
    for i, row in enumerate(rows.tolist()):
        if bar is not None:
            bar.update(1)
        p = dict(fixed)
        p.update(zip(names, row, strict=True))
        try:
            v = shape.convert(func(p))
        except Exception as exc:  # a metric failing for some draws is expected, not fatal
            if not first_error:
                first_error = f"draw {start + i}: {type(exc).__name__}: {exc}"
            continue
        if values.ndim == 1 and shape.names:  # the first vector: widen the failures so far
            if n * len(shape.names) > _MAX_VALUES:
                raise PropagationError(
                    f"n_samples={n}: {n} draws of a metric with {len(shape.names)} values "
                    f"would not fit in memory (at most {_MAX_VALUES} values)"
                )
            values = np.full((n, len(shape.names)), np.nan)
        values[i] = v
    if bar is not None:
        bar.close()
    bad = ~np.isfinite(values)
    if np.any(bad):
        values[bad] = np.nan  # infinities count as failures, as NaN does
        if not first_error:
            first = int(np.flatnonzero(~_complete(values))[0])
            first_error = f"draw {start + first}: a non-finite value"
    return PropagationBatch(
        start=start,
        values=values,
        seed=seed,
        source="covariance" if src.cov is not None else "posterior",
        names=shape.names or (),
        first_error=first_error,
        origin=src.digest,
        metric=metric_identity(func),
    )


def _percentiles(percentiles: Sequence[float]) -> list[float]:
    # A string is iterable: "50" would read as the percentiles 5 and 0.
    if isinstance(percentiles, (str, bytes)):
        raise PropagationError(
            f"percentiles must be a list of numbers in [0, 100], got the string {percentiles!r}"
        )
    try:
        values: list[Any] = list(percentiles)
    except TypeError:
        values = [None]
    read = [as_float(p) for p in values]  # text and True are no percentile
    pcts = [p for p in read if p is not None]
    if len(pcts) != len(read):
        raise PropagationError(
            f"percentiles must be a list of numbers in [0, 100], got {plain(percentiles)}"
        )
    if not pcts:  # a result without any percentile would be silently incomplete
        raise PropagationError("percentiles must name at least one percentile in [0, 100]")
    if any(not 0.0 <= p <= 100.0 for p in pcts):
        shown = ", ".join(f"{p:g}" for p in pcts)
        raise PropagationError(f"percentiles must lie in [0, 100], got [{shown}]")
    return pcts


def _labels(pcts: list[float]) -> list[tuple[str, float]]:
    """``"P2.5"``-style labels of the distinct levels; in full where ``:g`` would merge two."""
    levels = list(dict.fromkeys(pcts))
    short = [f"P{p:g}" for p in levels]
    return [
        (label if short.count(label) == 1 else f"P{p!r}", p)
        for label, p in zip(short, levels, strict=True)
    ]


def _shape_of(batches: Sequence[PropagationBatch]) -> tuple[str, ...]:
    """Component names shared by the batches (() for a scalar metric), else an error."""
    vector = {b.names for b in batches if b.values.ndim == 2}
    if len(vector) > 1:
        raise PropagationError(
            "batches of different metrics cannot be combined "
            f"(components {' and '.join(str(list(v)) for v in sorted(vector))})"
        )
    if not vector:
        return ()
    names = vector.pop()
    for b in batches:
        # a 1-D batch beside vector ones is one whose every draw failed
        if b.values.ndim == 1 and np.any(np.isfinite(b.values)):
            raise PropagationError(
                f"batches of different metrics cannot be combined (a scalar metric and "
                f"components {list(names)})"
            )
    return names


def _statistics(
    values: FloatArray, pcts: list[float], n_samples: int, seed: int | None, source: str
) -> PropagationResult:
    ok = np.isfinite(values)
    good = values[ok]
    # spread measured on values scaled to order one: squares of a metric near 1e300
    # overflow where its standard deviation does not
    top = float(np.max(np.abs(good))) if good.size else 0.0
    unit = top if 1e150 < top < np.inf else 1.0
    scaled = good / unit if unit != 1.0 else good
    return PropagationResult(
        mean=float(scaled.mean() * unit),
        std=float(scaled.std(ddof=1) * unit) if good.size > 1 else float("nan"),
        percentiles={label: float(np.percentile(good, p)) for label, p in _labels(pcts)},
        percentile_levels=tuple(dict.fromkeys(pcts)),
        samples=good,
        n_samples=n_samples,
        n_failed=int((~ok).sum()),
        seed=seed,
        source=source,
    )


def _combine(
    batches: Sequence[PropagationBatch], pcts: list[float], stacklevel: int
) -> PropagationResult | VectorPropagationResult:
    if isinstance(batches, (PropagationBatch, str, bytes)) or not hasattr(batches, "__iter__"):
        raise PropagationError(
            f"batches: expected a sequence of PropagationBatch, got {type(batches).__name__}"
        )
    batches = list(batches)
    for i, b in enumerate(batches):
        if not isinstance(b, PropagationBatch):
            raise PropagationError(
                f"batches[{i}]: expected a PropagationBatch (from propagate_batch), "
                f"got {type(b).__name__}"
            )
    if not batches:
        raise PropagationError("combine_batches needs at least one batch")
    first = batches[0]
    for b in batches:
        if b.seed != first.seed or b.source != first.source:
            raise PropagationError(
                "batches of different propagations cannot be combined "
                f"(seed {first.seed} from the {first.source}, seed {b.seed} from the {b.source})"
            )
        if b.origin != first.origin:
            raise PropagationError(
                "batches of different results cannot be combined (draws from the result "
                f"with digest {first.origin or '?'} and from {b.origin or '?'})"
            )
        if b.metric != first.metric:
            raise PropagationError(
                "batches of different metrics cannot be combined "
                f"({first.metric or '?'} and {b.metric or '?'})"
            )
    # an empty batch covers no draws, wherever it starts
    ordered = sorted((b for b in batches if b.values.shape[0]), key=lambda b: b.start)
    if not ordered:
        raise PropagationError("the batches hold no draws")
    at = 0
    for b in ordered:
        if b.start != at:
            what = "overlap" if b.start < at else "leave a gap"
            raise PropagationError(f"batches {what} at draw {min(at, b.start)}")
        at = b.stop
    names = _shape_of(ordered)
    parts = [
        np.full((b.values.shape[0], len(names)), np.nan)
        if names and b.values.ndim == 1
        else np.asarray(b.values)
        for b in ordered
    ]
    values = np.concatenate(parts)
    n_samples = int(values.shape[0])
    complete = _complete(values)
    n_failed = int((~complete).sum())
    first_error = next((b.first_error for b in ordered if b.first_error), "")
    because = f" (first failure: {first_error})" if first_error else ""
    if not np.any(np.isfinite(values)):
        raise PropagationError(f"the metric failed for all {n_samples} draws{because}")
    empty = [name for j, name in enumerate(names) if not np.any(np.isfinite(values[:, j]))]
    if empty:
        raise PropagationError(
            f"the metric's component(s) {empty} failed for all {n_samples} draws{because}"
        )
    if n_failed > FAILURE_WARNING_FRACTION * n_samples:
        warnings.warn(
            f"propagate: the metric failed for {n_failed} of {n_samples} draws "
            f"({100.0 * n_failed / n_samples:.3g} %), excluded from the statistics{because}",
            UserWarning,
            stacklevel=stacklevel + 1,
        )
    if not names:
        return _statistics(values, pcts, n_samples, first.seed, first.source)
    return VectorPropagationResult(
        components={
            name: _statistics(values[:, j], pcts, n_samples, first.seed, first.source)
            for j, name in enumerate(names)
        },
        values=values,
        n_samples=n_samples,
        n_failed=n_failed,
        seed=first.seed,
        source=first.source,
    )


def combine_batches(
    batches: Sequence[PropagationBatch],
    *,
    percentiles: Sequence[float] = (2.5, 50.0, 97.5),
) -> PropagationResult | VectorPropagationResult:
    """Pool batches covering draws ``0 .. n`` of one seed into a `PropagationResult`.

    The result is the one `propagate` returns for ``n_samples=n`` and that
    seed, bit for bit, whatever the batches' sizes and order (a
    `VectorPropagationResult` for a metric with several values).

    Parameters
    ----------
    batches : sequence of PropagationBatch
        Together exactly the draws ``0 .. n``, each once, in any order.
    percentiles : sequence of float
        Percentiles to report (``"P2.5"`` etc.).

    Raises
    ------
    PropagationError
        Something other than `PropagationBatch` objects given, batches of
        different propagations (another seed, or another result: the batches'
        `origin` differ) or metrics (their `metric` differ), gaps or
        overlaps, or a metric that failed for every draw.

    Warns
    -----
    UserWarning
        When more than 1 % of the draws failed.
    """
    return _combine(batches, _percentiles(percentiles), stacklevel=2)


@overload
def propagate(
    result: Any,
    func: Callable[[dict[str, float]], float],
    *,
    n_samples: int = ...,
    percentiles: Sequence[float] = ...,
    seed: int | None = ...,
    progress: bool = ...,
) -> PropagationResult: ...


@overload
def propagate(
    result: Any,
    func: Callable[[dict[str, float]], Mapping[str, float] | Sequence[float] | FloatArray],
    *,
    n_samples: int = ...,
    percentiles: Sequence[float] = ...,
    seed: int | None = ...,
    progress: bool = ...,
) -> VectorPropagationResult: ...


@small_blas
def propagate(
    result: Any,
    func: Callable[[dict[str, float]], Any],
    *,
    n_samples: int = 1000,
    percentiles: Sequence[float] = (2.5, 50.0, 97.5),
    seed: int | None = None,
    progress: bool = False,
) -> PropagationResult | VectorPropagationResult:
    """Push parameter uncertainty through a metric by Monte Carlo.

    Parameters
    ----------
    result : IdentificationResult, InferenceResult, TransferFunctionFit or EquivalentSystemFit
        Draws from a result's parameters and covariance (any estimator's
        result with ``parameter_names``; a fit's `standard_errors` name the
        covariance's rows, and an `EquivalentSystemFit` draws its own
        parameters, ``K, 1/T_theta2, zeta, omega, tau``: compute ``T_theta2``
        from ``1/T_theta2``), or rows resampled (with replacement) from a
        posterior's samples, so skew, bounds and correlations of the
        posterior are kept. Refused: a covariance with non-finite entries,
        a negative variance, or one that is not positive semi-definite.
    func : callable
        ``func(parameters: dict) -> float``; gets fixed and drawn parameters.
        A metric with several values returns a sequence (or 1-D array) of
        floats, whose components are named ``"<func name>[i]"``, or a mapping
        of names to floats (keyed by name: the same keys in another order
        are the same components, in the order of the first draw). The first
        draw that returns a value fixes the shape; draws of another shape
        count as failed.
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
    PropagationResult or VectorPropagationResult
        A `PropagationResult` for a scalar metric; for one with several
        values a `VectorPropagationResult`, a `PropagationResult` per
        component. Draws where `func` raises or returns a non-finite value
        are counted in ``n_failed``; they do not stop the run.

    Raises
    ------
    PropagationError
        Bad arguments (an empty `percentiles`, a `progress` that is not a
        bool, more draws than fit in memory), or the metric failed for every
        draw (the message quotes the first failure).

    Warns
    -----
    UserWarning
        When the metric failed for more than 1 % of the draws (the message
        gives the count and the first failure).

    See Also
    --------
    propagate_batch, combine_batches : the same draws split into batches that
        run anywhere (the pipeline's ``propagate: {n_batches: k}``).

    Notes
    -----
    The draws from a covariance make the statement the result's own
    `interval` makes. That interval takes Student's t with each parameter's
    `degrees_of_freedom` (few for coloured residuals, whose error bars rest
    on a short residual spectrum), so plain Gaussian draws would give a
    band z/t narrower (0.8 of it at 6 degrees of freedom) and cover the
    truth less often than the interval does. A multivariate t has one
    degrees-of-freedom count for all parameters, which they do not share.
    So the draws are a Gaussian copula with t marginals: correlated normal
    draws ``z`` (correlations of the covariance), each parameter
    ``mean + se * t_nu^-1(Phi(z))`` with its own ``nu`` (floored at one, as
    `interval` floors it). The identity metric ``p -> p[name]`` then has
    exactly `interval`'s band in distribution, and every draw keeps the
    ranks (rank correlations) of the Gaussian draws. A parameter without
    degrees of freedom (infinite: the normal quantile) is drawn as before,
    bit for bit. A function of several parameters has no one t statement
    (its parameters' counts differ); its band is the copula's, wider than
    the normal draws' where those parameters have few degrees of freedom.
    """
    n = whole_number(n_samples, "n_samples", PropagationError)
    pcts = _percentiles(percentiles)
    batch = propagate_batch(
        result, func, start=0, n_samples=n, seed=_check_seed(seed), progress=progress
    )
    return _combine([batch], pcts, stacklevel=CALLER_STACKLEVEL)
