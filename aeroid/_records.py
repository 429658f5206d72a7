"""Small helpers shared by the frozen result records."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, NoReturn

import numpy as np
from numpy.typing import ArrayLike, NDArray


def frozen_array(values: ArrayLike) -> NDArray[np.float64]:
    """A read-only float64 copy."""
    out = np.array(values, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def frozen_complex(values: ArrayLike) -> NDArray[np.complex128]:
    """A read-only complex128 copy."""
    out = np.array(values, dtype=np.complex128, copy=True)
    out.setflags(write=False)
    return out


class ReadOnlyDict(dict[str, Any]):
    """A plain `dict` that refuses changes.

    Parameter sets cross every user boundary as dicts (``json.dumps``,
    ``isinstance(p, dict)`` and ``**p`` work); inside a frozen result they
    must not change, so the mutating methods raise. ``dict(p)`` or
    ``p.copy()`` gives an ordinary, mutable copy.
    """

    __slots__ = ()

    def _refuse(self, *args: Any, **kwargs: Any) -> NoReturn:
        raise TypeError("this mapping belongs to a frozen record; change a copy: dict(...)")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _refuse
    __ior__ = _refuse

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (dict(self),))

    def __copy__(self) -> ReadOnlyDict:
        return self

    def __deepcopy__(self, memo: dict[int, Any]) -> ReadOnlyDict:
        return self  # immutable, and its values are floats, strings or read-only arrays


def frozen_mapping(values: Mapping[str, Any] | Iterable[tuple[str, Any]]) -> Mapping[str, Any]:
    """A read-only dict; float-like values become Python floats, arrays become read-only."""
    out: dict[str, Any] = {}
    for k, v in dict(values).items():
        if isinstance(v, np.ndarray) and v.ndim > 0:
            out[str(k)] = frozen_array(v)
        elif isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool):
            out[str(k)] = float(v)
        else:
            out[str(k)] = v
    return ReadOnlyDict(out)


def fmt(value: float, digits: int = 4) -> str:
    """Compact significant-digit formatting used in every summary table.

    None and NaN (an undefined metric: no ω_180, no coherent band) print "—", not a
    number; an infinite value (an unbounded standard error) prints as ``inf``.
    """
    if value is None or np.isnan(value):
        return "—"
    if not np.isfinite(value):
        return str(float(value))
    return f"{value:.{digits}g}"


def fmt_fixed(value: float, decimals: int) -> str:
    """`value` with `decimals` places for a summary table; "—" where undefined (NaN)."""
    if value is None or np.isnan(value):
        return "—"
    return f"{value:.{decimals}f}"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A GitHub-flavoured Markdown table with padded columns."""
    body = [[str(c) for c in r] for r in rows]
    head = [str(h) for h in header]
    widths = [
        max(len(head[j]), *(len(r[j]) for r in body)) if body else len(head[j])
        for j in range(len(head))
    ]

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)) + " |"

    out = [line(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out.extend(line(r) for r in body)
    return "\n".join(out)


#: What every estimator's result offers (`identify`, `check_compatibility`,
#: `equation_error`, `stepwise_regression`, `identify_frequency_domain`,
#: `fit_transfer_function`, `equivalent_system`, `infer`): estimates and standard
#: errors by parameter name (``stderr`` and ``standard_errors`` are one mapping),
#: their covariance, a Markdown `summary` and a `plot`.
ESTIMATE_PROTOCOL = (
    "parameters",
    "stderr",
    "standard_errors",
    "covariance",
    "summary",
    "plot",
    "margin",
    "interval",
)


class _Packed:
    """A read-only array, mapping proxy or read-only dict in a form pickle carries."""

    def __init__(self, kind: str, value: Any) -> None:
        self.kind = kind
        self.value = value


def _pack(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value if value.flags.writeable else _Packed("array", value)
    if isinstance(value, MappingProxyType):
        return _Packed("proxy", {k: _pack(v) for k, v in value.items()})
    if isinstance(value, ReadOnlyDict):
        return _Packed("dict", {k: _pack(v) for k, v in value.items()})
    if type(value) is dict:
        return {k: _pack(v) for k, v in value.items()}
    if type(value) in (tuple, list):
        return type(value)(_pack(v) for v in value)
    return value


def _unpack(value: Any) -> Any:
    if isinstance(value, _Packed):
        if value.kind == "array":
            value.value.setflags(write=False)
            return value.value
        items = {k: _unpack(v) for k, v in value.value.items()}
        return MappingProxyType(items) if value.kind == "proxy" else ReadOnlyDict(items)
    if type(value) is dict:
        return {k: _unpack(v) for k, v in value.items()}
    if type(value) in (tuple, list):
        return type(value)(_unpack(v) for v in value)
    return value


class FrozenState:
    """Pickling and copying of a frozen record: what was read-only comes back read-only.

    A mapping proxy cannot be pickled, and an unpickled or deep-copied array is
    writable; the record's state carries both in a form that can, and restores them.
    """

    __slots__ = ()

    def __getstate__(self) -> dict[str, Any]:
        return {k: _pack(v) for k, v in vars(self).items()}

    def __setstate__(self, state: Mapping[str, Any]) -> None:
        for k, v in state.items():
            object.__setattr__(self, k, _unpack(v))


class IntervalMixin(FrozenState):
    """`margin` and `interval` for a result with `parameters`, `stderr` and (where the
    estimator knows them) `degrees_of_freedom`: Student's t with each estimate's
    degrees of freedom, the normal quantile where none is given."""

    def margin(self, level: float = 0.95) -> Mapping[str, float]:
        """Half-width of each estimate's two-sided `level` interval: its standard
        error times the t quantile of its degrees of freedom."""
        from ._stats import margins

        dof = dict(getattr(self, "degrees_of_freedom", None) or {})
        return ReadOnlyDict(margins(dict(self._margin_stderr()), dof, level))

    def _margin_stderr(self) -> Mapping[str, float]:
        """The standard errors `margin` covers (a result with more estimates widens it)."""
        stderr: Mapping[str, float] = self.stderr  # type: ignore[attr-defined]
        return stderr

    def interval(self, level: float = 0.95) -> Mapping[str, tuple[float, float]]:
        """Each estimate's two-sided `level` interval, ``name -> (lower, upper)``."""
        half = self.margin(level)
        values = self._interval_values()
        return ReadOnlyDict({n: (v - half[n], v + half[n]) for n, v in values.items() if n in half})

    def _interval_values(self) -> Mapping[str, float]:
        """The estimates `interval` centres on, by the names `margin` uses."""
        values: Mapping[str, float] = self.parameters  # type: ignore[attr-defined]
        return values
