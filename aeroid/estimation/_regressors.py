"""Regressors from flight data: channels, arrays, expressions; candidate pools.

Split out of `aeroid.estimation.regression` (which re-exports every name): the parsing of
regressor expressions into columns and the candidate pools of stepwise
regression.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import named_columns
from .._value_checks import check_distinct
from ..errors import AeroidError, ChannelError, DataFormatError
from ..io.data import FlightData, as_float, positive_number, real_array, uniform_step

FloatArray = NDArray[np.float64]

_CONST = "const"
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
# the absolute value of a channel, ``abs(beta)``: the nonsmooth regressor of a model
# even in an angle with a corner at zero (Klein & Morelli ch. 5)
_ABS = re.compile(r"^abs\((.*)\)$")


def _evaluate(lookup: Mapping[str, Any], expr: str, n: int, role: str) -> FloatArray:
    """Value of a channel name or a product/quotient/power expression of channels."""
    if repr(expr) not in role:
        role = f"{role} {expr!r}"
    if expr in lookup:
        column = np.asarray(lookup[expr], dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(column))
        if bad.size:
            raise DataFormatError(f"{role}: non-finite value at sample {int(bad[0])}")
        return column
    text = expr.replace("**", "^").replace(" ", "")
    if not text:
        raise DataFormatError(f"{role}: empty expression")
    parts = re.split(r"([*/])", text)
    out = np.ones(n)
    op = "*"
    for k, part in enumerate(parts):
        if k % 2 == 1:
            op = part
            continue
        base, caret, power = part.partition("^")
        if not base or (caret and not power):  # "a^" is a power with nothing to raise to
            raise DataFormatError(f"{role}: cannot parse {part!r}")
        absolute = _ABS.match(base)
        if absolute:
            inner = absolute.group(1)
            if inner not in lookup:
                raise ChannelError(
                    f"{role}: {part!r} takes the absolute value of {inner!r}, which is not a "
                    f"channel; channels present: {sorted(lookup)}"
                )
            value: Any = np.abs(np.asarray(lookup[inner], dtype=np.float64))
        elif "(" in base or ")" in base:
            raise DataFormatError(
                f"{role}: cannot parse {part!r} (the one function is abs(<channel>))"
            )
        elif _NUMBER.match(base):
            value = float(base)
        elif base in lookup:
            value = np.asarray(lookup[base], dtype=np.float64)
        else:
            hint = (
                f"; {_CONST!r} is the constant term, added by intercept=True"
                if base == _CONST
                else ""
            )
            raise ChannelError(
                f"{role}: channel {base!r} not found; channels present: {sorted(lookup)}{hint}"
            )
        if power:
            if not _NUMBER.match(power):
                raise DataFormatError(f"{role}: power {power!r} is not a number")
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                value = np.power(value, float(power))
        # overflow and division by zero are reported below, by name, not as warnings
        with np.errstate(all="ignore"):
            out = out * value if op == "*" else out / value
    if not np.all(np.isfinite(out)):
        raise DataFormatError(
            f"{role}: non-finite value (division by zero, or a negative number to a fractional power?)"
        )
    return out


def _column(lookup: Mapping[str, Any], value: Any, n: int, role: str) -> FloatArray:
    if isinstance(value, str):
        return _evaluate(lookup, value, n, role)
    arr = real_array(value, role)
    if arr.shape != (n,):
        raise DataFormatError(f"{role}: expected {n} samples, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(
            f"{role}: non-finite value at sample {int(np.argmin(np.isfinite(arr)))}"
        )
    return arr


def _mapping_columns(data: Mapping[Any, Any]) -> tuple[dict[str, FloatArray], int]:
    """A mapping's entries as named 1-D float arrays of one length, and that length."""
    lookup = {str(k): real_array(v, f"data[{str(k)!r}]") for k, v in data.items()}
    if not lookup:
        raise DataFormatError("data: the mapping holds no channels")
    first, n = None, -1
    for name, col in lookup.items():
        if col.ndim != 1:
            raise DataFormatError(f"data[{name!r}]: expected a 1-D array, got shape {col.shape}")
        if first is None:
            first, n = name, col.shape[0]
        elif col.shape[0] != n:
            raise DataFormatError(
                f"data[{name!r}]: {col.shape[0]} samples where data[{first!r}] has {n}"
            )
    return lookup, n


def _resolve(
    data: Any, response: Any, regressors: Any, what: str
) -> tuple[FloatArray, FloatArray, list[str], str, FloatArray | None]:
    """Response, regressor matrix, regressor names, response name and time axis."""
    time: FloatArray | None = None
    frame = _frame_columns(data)
    if frame is not None:
        # a table's columns are named: read by name, never by position
        data = frame
        if regressors is None:
            regressors = [c for c in frame if c != response]
    if _several_records(data) is not None:
        raise DataFormatError(
            f"data: {what} takes one record (a FlightData, a mapping or a matrix); "
            "several records are fitted together by equation_error"
        )
    if isinstance(data, FlightData):
        lookup: Mapping[str, Any] = data.channels
        n = data.n_samples
        time = np.asarray(data.time)
    elif isinstance(data, Mapping):
        lookup, n = _mapping_columns(data)
    else:
        if isinstance(data, (str, bytes)):
            raise DataFormatError(
                "data: expected FlightData, a mapping of arrays or a regressor matrix, got str"
            )
        mat = real_array(data, "data (a regressor matrix)")
        if mat.ndim != 2:
            raise DataFormatError(
                f"data: a regressor matrix must be 2-D (samples, regressors), got shape {mat.shape}"
            )
        if not np.all(np.isfinite(mat)):
            raise DataFormatError("data: the regressor matrix holds non-finite values")
        n, p = mat.shape
        if regressors is None:
            names = [f"x{j + 1}" for j in range(p)]
        elif isinstance(regressors, str) or len(regressors) != p:
            raise DataFormatError(
                f"regressors: with a regressor matrix give {p} names, got {regressors!r}"
            )
        else:
            names = [str(r) for r in regressors]
        z = _column({}, response, n, "response") if not isinstance(response, str) else None
        if z is None:
            raise DataFormatError("response: with a regressor matrix give the response samples")
        return z, mat, names, "z", None
    if isinstance(response, str):
        zname = response
        z = _evaluate(lookup, response, n, "response")
    else:
        zname = "z"
        z = _column(lookup, response, n, "response")
    if regressors is None:
        role = "candidates" if what.startswith("stepwise") else "regressors"
        raise DataFormatError(f"{role}: required for {what} on flight data or a mapping")
    if isinstance(regressors, str):
        regressors = [regressors]
    if not isinstance(regressors, (Mapping, Sequence)):
        role = "candidates" if what.startswith("stepwise") else "regressors"
        raise DataFormatError(
            f"{role}: expected names or expressions, or a mapping of name to samples, "
            f"got {type(regressors).__name__}"
        )
    if isinstance(regressors, Mapping):
        items = [(str(k), v) for k, v in regressors.items()]
    else:
        items = []
        for r in regressors:
            if not isinstance(r, str):
                raise DataFormatError(
                    "regressors: give names/expressions, or a mapping of name to samples"
                )
            items.append((r, r))
    cols = [_column(lookup, v, n, f"regressor {k!r}") for k, v in items]
    mat = np.column_stack(cols) if cols else np.zeros((n, 0))
    return z, mat, [k for k, _ in items], zname, time


def _frame_columns(data: Any) -> dict[str, Any] | None:
    """The columns of a table with named columns (a pandas DataFrame) by name, or None."""
    if isinstance(data, FlightData):
        return None
    try:
        columns = named_columns(data)
    except DataFormatError as exc:
        raise DataFormatError(f"data: {exc}") from None
    return columns if columns is not None and hasattr(data, "columns") else None


def _several_records(data: Any) -> list[FlightData] | None:
    """`data` as a list of records when it is a sequence of FlightData (None otherwise:
    a nested list of numbers is a regressor matrix, not records)."""
    if isinstance(data, (FlightData, Mapping, str, bytes, np.ndarray)):
        return None
    if not isinstance(data, Sequence):
        return None
    if not data:
        raise DataFormatError(
            "data: empty; give a FlightData, a list of them, a mapping or a regressor matrix"
        )
    kinds = [isinstance(d, FlightData) for d in data]
    if not any(kinds):
        return None
    if not all(kinds):
        j = kinds.index(False)
        raise DataFormatError(
            f"data: several records must all be FlightData; item {j} is {type(data[j]).__name__}"
        )
    return list(data)


def _resolve_records(
    records: Sequence[FlightData], response: Any, regressors: Any, what: str
) -> tuple[FloatArray, FloatArray, list[str], str, FloatArray, tuple[int, ...]]:
    """`_resolve` on each record, stacked: response, regressors, names, response name,
    the records' times one after another, and each record's length."""
    if not isinstance(response, str):
        raise DataFormatError(
            "response: with several records give a channel name or expression, not samples"
        )
    if isinstance(regressors, Mapping) and any(not isinstance(v, str) for v in regressors.values()):
        raise DataFormatError(
            "regressors: with several records give names or expressions, not samples"
        )
    parts = []
    for k, record in enumerate(records):
        try:
            parts.append(_resolve(record, response, regressors, what))
        except AeroidError as exc:
            raise type(exc)(f"record {k}: {exc}") from None
    z = np.concatenate([part[0] for part in parts])
    x = np.concatenate([part[1] for part in parts])
    time = np.concatenate([np.asarray(part[4], dtype=np.float64) for part in parts])
    lengths = tuple(part[0].shape[0] for part in parts)
    return z, x, parts[0][2], parts[0][3], time, lengths


def _check_names(names: Sequence[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise DataFormatError(f"regressors: the name {name!r} appears twice")
        seen.add(name)


def _with_constant(
    x: FloatArray, names: list[str], intercept: bool
) -> tuple[FloatArray, list[str]]:
    """The regressor columns with the constant term first if asked, names checked."""
    if intercept:
        names = [_CONST, *names]
        x = np.column_stack([np.ones(x.shape[0]), x])
    _check_names(names)
    if x.shape[1] == 0:
        raise DataFormatError("regressors: none given and no constant term")
    return x, names


def _step_of(time: FloatArray | None, dt: float | None) -> float | None:
    if time is not None:
        found = uniform_step(np.asarray(time, dtype=np.float64))
        if found is None or not found > 0.0:
            return None
        step = found
        if dt is not None and not np.isclose(
            positive_number(dt, "dt", " of seconds"), step, rtol=1e-6
        ):
            raise DataFormatError(f"dt: {dt!r} contradicts the data's sample interval {step:.6g} s")
        return step
    if dt is None:
        return None
    return positive_number(dt, "dt", " of seconds")


def spline_terms(
    x: ArrayLike, knots: Sequence[float], *, name: str = "alpha", degree: int = 1
) -> dict[str, FloatArray]:
    """Truncated-power spline columns ``max(x − k, 0)^degree`` for each knot.

    Parameters
    ----------
    x : array_like, shape (n,)
        The variable (typically the angle of attack).
    knots : sequence of float
        Knot positions in the units of `x`.
    name : str
        Name of the variable in the column names, ``"(alpha-0.1)+"`` or
        ``"(alpha-0.1)+^2"``.
    degree : int
        Power of the truncated term (1: a change of slope at the knot).

    Returns
    -------
    dict of str to ndarray
    """
    arr = real_array(x, f"spline_terms: {name}")
    if arr.ndim != 1 or not np.all(np.isfinite(arr)):
        raise DataFormatError(f"spline_terms: {name} must be a finite 1-D array")
    if isinstance(degree, bool) or not isinstance(degree, (int, np.integer)) or degree < 1:
        raise DataFormatError(f"degree: expected a positive integer, got {degree!r}")
    if isinstance(knots, (str, bytes)) or not isinstance(knots, Sequence | np.ndarray):
        raise DataFormatError(f"knots of {name}: expected a sequence of numbers, got {knots!r}")
    out: dict[str, FloatArray] = {}
    for k in knots:
        knot = as_float(k)
        if knot is None or not np.isfinite(knot):
            raise DataFormatError(f"knots of {name}: expected finite numbers, got {k!r}")
        label = f"({name}-{knot:g})+" if knot >= 0 else f"({name}+{-knot:g})+"
        if degree > 1:
            label += f"^{degree}"
        if label in out:  # the same knot to the label's precision: the same column
            raise DataFormatError(f"knots of {name}: {knot:g} is given twice")
        with np.errstate(over="ignore"):
            column = np.maximum(arr - knot, 0.0) ** degree
        if not np.all(np.isfinite(column)):
            raise DataFormatError(f"spline {label}: overflows (degree {degree} too high?)")
        out[label] = column
    return out


def candidate_pool(
    data: FlightData | Mapping[str, ArrayLike],
    variables: Sequence[str],
    *,
    squares: bool = True,
    products: bool = True,
    cubes: bool = False,
    absolutes: bool | Sequence[str] = False,
    splines: Mapping[str, Sequence[float]] | None = None,
) -> dict[str, FloatArray]:
    """Candidate regressors for `stepwise_regression` built from a few variables.

    Parameters
    ----------
    data : FlightData or mapping of str to array_like
        Where the variables come from.
    variables : sequence of str
        Channel names or expressions (e.g. ``"alpha"``, ``"q*cbar/V"`` is not
        allowed — put scaled rates in the mapping or data first).
    squares, products, cubes : bool
        Add ``v^2`` for each variable, ``v*w`` for each pair, ``v^3``.
    absolutes : bool or sequence of str
        Add ``abs(v)`` for each variable (True) or for those named, and its
        product ``abs(v)*w`` with each other variable: the nonsmooth candidates
        of an effect even in `v` with a corner at zero (sideslip drag, V-shaped
        in β), which no polynomial in `v` follows. Each must be a channel name.
    splines : mapping of str to sequence of float, optional
        Knots of first-degree splines per variable, ``{"alpha": [0.1, 0.2]}``.

    Returns
    -------
    dict of str to ndarray
        Name to column, in the order: linear terms, squares, products, cubes,
        absolute values (each followed by its products), splines. Names are
        expressions `equation_error` also understands (except the splines).
    """
    if isinstance(variables, str):
        variables = [variables]
    if not isinstance(variables, Sequence) or not all(isinstance(v, str) for v in variables):
        raise DataFormatError(
            f"variables: expected channel names or expressions, got {variables!r}"
        )
    if not variables:
        raise DataFormatError("variables: give at least one variable")
    check_distinct(variables, "variables", DataFormatError)
    data = _frame_columns(data) or data
    if isinstance(data, FlightData):
        lookup: Mapping[str, Any] = data.channels
        n = data.n_samples
    elif isinstance(data, Mapping):
        lookup, n = _mapping_columns(data)
    else:
        raise DataFormatError("data: expected FlightData or a mapping of name to samples")
    if splines is not None and not isinstance(splines, Mapping):
        raise DataFormatError(f"splines: expected a mapping of variable to knots, got {splines!r}")
    cols = {v: _evaluate(lookup, v, n, "variable") for v in variables}
    out: dict[str, FloatArray] = dict(cols)
    if squares:
        out.update({f"{v}^2": cols[v] ** 2 for v in variables})
    if products:
        for i, a in enumerate(variables):
            for b in variables[i + 1 :]:
                out[f"{a}*{b}"] = cols[a] * cols[b]
    if cubes:
        out.update({f"{v}^3": cols[v] ** 3 for v in variables})
    for v in _absolute_variables(absolutes, variables):
        out[f"abs({v})"] = np.abs(cols[v])
        for w in variables:
            if w != v:
                out[f"abs({v})*{w}"] = out[f"abs({v})"] * cols[w]
    for v, knots in dict(splines or {}).items():
        if v not in cols:
            cols[v] = _evaluate(lookup, v, n, "spline variable")
        out.update(spline_terms(cols[v], knots, name=v))
    return out


def _absolute_variables(absolutes: bool | Sequence[str], variables: Sequence[str]) -> list[str]:
    """The variables `candidate_pool` takes the absolute value of."""
    if absolutes is True:
        chosen = list(variables)
    elif absolutes is False or absolutes is None:
        return []
    elif isinstance(absolutes, str):
        chosen = [absolutes]
    elif isinstance(absolutes, Sequence) and all(isinstance(a, str) for a in absolutes):
        chosen = list(absolutes)
    else:
        raise DataFormatError(
            f"absolutes: expected True, False or a list of variables, got {absolutes!r}"
        )
    unknown = [a for a in chosen if a not in variables]
    if unknown:
        raise DataFormatError(f"absolutes: {unknown} are not among the variables {list(variables)}")
    odd = [a for a in chosen if not a.isidentifier()]
    if odd:
        raise DataFormatError(
            f"absolutes: {odd} are expressions; abs(...) takes a channel name (put the "
            "expression in the mapping or data first)"
        )
    return chosen
