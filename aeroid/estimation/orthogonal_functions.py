"""Multivariate orthogonal function modelling (Morelli 1995; Klein & Morelli ch. 5).

A global polynomial model of a coefficient in several explanatory variables
(angle of attack, Mach number ...) whose terms are chosen by the data. The
candidate terms are the monomials of the variables up to a power per
variable and a total order; they are generated order by order, each new one
a variable times a monomial of the order below, and made orthogonal over the
data to every function generated before it (Gram-Schmidt). On orthogonal
functions the least-squares coefficients decouple, ``a_k = z'p_k / p_k'p_k``,
and each function lowers the squared fit error by ``a_k^2 p_k'p_k``
independently of the others, so the functions are ranked by that reduction
and the number kept is the one that minimises the predicted squared error

    PSE(j) = SSE_j / N + 2 sigma2_max j / N,

``sigma2_max`` an upper bound on the noise variance (Barron's criterion with
the factor two for an unknown structure). Each kept function is then written
back as the monomials it was built from, and their coefficients summed: an
ordinary polynomial. The orthogonal coefficients are uncorrelated with
variance ``sigma^2 / p_k'p_k``, so the polynomial's covariance follows
exactly from the back-transformation.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._checks import as_float, plain
from .._colour import colored_covariance
from .._records import IntervalMixin, fmt, frozen_array, frozen_mapping, markdown_table
from .._value_checks import check_distinct, real_array, whole_number
from ..errors import DataFormatError, IdentificationError
from ..io.data import FlightData
from ._regressors import _resolve

__all__ = ["OrthogonalFunctionResult", "orthogonal_function_model"]

FloatArray = NDArray[np.float64]

# Generation stops once the functions fit the data to this rms (relative to the data).
_PERFECT_FIT = 1e-6
# A term whose rms contribution is below this fraction of the data's rms is dropped
# (Morelli's rule: it changes no prediction that matters).
_NEGLIGIBLE = 1e-3
# A function less than this fraction of its unorthogonalised norm is no new direction.
_DEPENDENT = 1e-9
_NOISE_BOUNDS = ("spread", "linear")
# Re-generations of the functions in the order of their effect before the order holds.
_REORDERINGS = 5


@dataclass(frozen=True, eq=False)
class OrthogonalFunctionResult(IntervalMixin):
    """A polynomial model chosen by multivariate orthogonal functions.

    Attributes
    ----------
    parameters, stderr : mapping of str to float
        The ordinary polynomial's coefficients by term (``"1"``, ``"alpha"``,
        ``"alpha^2*mach"`` ...) and their standard errors.
    covariance : ndarray, shape (p, p)
        Their covariance, in the order of `parameter_names`.
    parameter_names : tuple of str
    powers : ndarray of int, shape (p, n_variables)
        Each term's power of each variable.
    variable_names : tuple of str
    response_name : str
    n_functions : int
        Orthogonal functions kept.
    pse_history : ndarray
        The predicted squared error with the first 1, 2, ... ranked functions.
    noise_bound : float
        ``sigma2_max`` of the PSE.
    pse, r_squared, fit_error : float
        At the kept number; ``fit_error`` is ``sqrt(SSE / (N - n_functions))``.
    response, fitted, residuals : ndarray
    error_bars : {"white", "colored"}
    degrees_of_freedom : mapping of str to float
    """

    parameters: Mapping[str, float]
    stderr: Mapping[str, float]
    covariance: FloatArray
    parameter_names: tuple[str, ...]
    powers: NDArray[np.int64]
    variable_names: tuple[str, ...]
    response_name: str
    n_functions: int
    pse_history: FloatArray
    noise_bound: float
    pse: float
    r_squared: float
    fit_error: float
    response: FloatArray
    fitted: FloatArray
    residuals: FloatArray
    error_bars: str
    degrees_of_freedom: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("parameters", "stderr", "degrees_of_freedom"):
            object.__setattr__(self, name, frozen_mapping(getattr(self, name)))
        for name in ("covariance", "pse_history", "response", "fitted", "residuals"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        powers = np.array(self.powers, dtype=np.int64, copy=True)
        powers.setflags(write=False)
        object.__setattr__(self, "powers", powers)

    def predict(self, values: Mapping[str, ArrayLike]) -> FloatArray:
        """The polynomial at `values` (variable name -> samples)."""
        missing = [v for v in self.variable_names if v not in values]
        if missing:
            raise DataFormatError(f"predict: no values for {missing}")
        cols = [real_array(values[v], f"predict: {v!r}") for v in self.variable_names]
        try:
            x = np.column_stack([c.ravel() for c in np.broadcast_arrays(*cols)])
        except ValueError:
            shapes = {v: np.shape(c) for v, c in zip(self.variable_names, cols, strict=True)}
            raise DataFormatError(f"predict: the values do not match in shape: {shapes}") from None
        coef = np.array([self.parameters[n] for n in self.parameter_names])
        return np.asarray(_monomials(x, self.powers) @ coef)

    def summary(self) -> str:
        """A Markdown table of the polynomial's terms, with the selection's figures."""
        rows = []
        for name in self.parameter_names:
            est, se = self.parameters[name], self.stderr[name]
            rows.append([name, fmt(est), fmt(se), fmt(abs(est) / se if se > 0 else np.inf, 3)])
        head = (
            f"Orthogonal function model of {self.response_name} in "
            f"{', '.join(self.variable_names)}: {self.n_functions} of "
            f"{self.pse_history.size} orthogonal functions kept (least predicted squared "
            f"error), {len(self.parameter_names)} polynomial terms, {self.error_bars} "
            "error bars\n\n"
        )
        tail = f"\n\nPSE = {fmt(self.pse)}, R² = {fmt(self.r_squared)}, s = {fmt(self.fit_error)}"
        return head + markdown_table(["term", "estimate", "std error", "|t|"], rows) + tail

    def plot(self) -> Any:
        """The predicted squared error against the functions kept, and the residuals."""
        from ..reports.plotting import figure

        fig, axes = figure(2, height=2.2)
        ax = axes[0, 0]
        n = np.arange(1, self.pse_history.size + 1)
        ax.plot(n, self.pse_history, marker="o", ms=3)
        ax.axvline(self.n_functions, color="C3", lw=0.8)
        ax.set_xlabel("orthogonal functions kept")
        ax.set_ylabel("PSE")
        ax = axes[1, 0]
        ax.plot(self.residuals, lw=0.8, color="C2")
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel("sample")
        ax.set_ylabel("residual")
        return fig


def orthogonal_function_model(
    data: FlightData | Mapping[str, ArrayLike] | ArrayLike,
    response: str | ArrayLike,
    variables: Sequence[str] | None = None,
    *,
    max_power: int | Sequence[int] | Mapping[str, int] = 4,
    max_order: int = 6,
    noise_variance: float | str = "spread",
    n_functions: int | None = None,
    prune: float = _NEGLIGIBLE,
    error_bars: str | None = None,
) -> OrthogonalFunctionResult:
    """Identify a polynomial model in several variables with orthogonal functions.

    Morelli's multivariate orthogonal function modelling (SIDPAC's ``offit``;
    module notes): candidate monomials up to `max_power` in each variable
    and `max_order` in all, made orthogonal over the data, ranked by how much
    each lowers the fit error, kept up to the least predicted squared error,
    and written back as an ordinary polynomial with its covariance.

    Parameters
    ----------
    data : FlightData, mapping of str to array_like, or array_like (n, k)
        Where the response and the variables come from (or the matrix of the
        variables' samples, then `variables` names its columns).
    response : str or array_like
        The modelled quantity, a channel name or samples.
    variables : sequence of str
        The explanatory variables (channel names or expressions).
    max_power : int, sequence of int or mapping of str to int
        The highest power of each variable in a term (one for all, one per
        variable in order, or by name: then every variable, 0 to leave one
        out); at most 8.
    max_order : int
        The highest total order of a term.
    noise_variance : float or {"spread", "linear"}
        The noise variance behind the PSE's bound ``sigma2_max``: a number
        (an independent estimate; the bound is 25 times it, five standard
        deviations), ``"linear"`` (four times the residual variance of a fit
        linear in the variables), or ``"spread"`` (half the response's
        variance about its mean: uniform errors as large as the data).
    n_functions : int, optional
        Keep this many ranked functions instead of the PSE's choice.
    prune : float
        Drop a polynomial term whose rms contribution over the data is below
        this fraction of the response's rms (Morelli's rule: the kept
        functions, written back, put tiny shares on many monomials); 0 keeps
        every term, and with every function kept the model is then ordinary
        least squares on the monomials. The residuals and the fit error are
        those of the polynomial returned.
    error_bars : {"white", "colored"}, optional
        Classical, or corrected for coloured residuals as `equation_error`
        corrects its own (the default for `FlightData`, a time series; a
        table's samples have no order in time, so white is its default).

    Returns
    -------
    OrthogonalFunctionResult

    Notes
    -----
    Generation stops at the order whose functions fit the data to a
    millionth of its rms (nothing is left to model). The error bars are
    those of the chosen structure: a function the PSE left out that carries
    part of the truth biases the terms it shares monomials with, and no bar
    covers that (the price of choosing the structure from the same data).

    Raises
    ------
    DataFormatError
        Malformed data or options; a missing, repeated or response variable.
    IdentificationError
        Fewer samples than candidate functions need, or a variable that is
        constant.
    """
    z, x, names, zname, _ = _resolve(data, response, variables, "orthogonal function model")
    n, k = x.shape
    if k == 0:
        raise DataFormatError("variables: name at least one")
    check_distinct(names, "variables", DataFormatError)
    if zname in names:
        raise DataFormatError(f"variables: {zname!r} is the response")
    cut = as_float(prune)
    if cut is None or not (np.isfinite(cut) and 0.0 <= cut < 1.0):
        raise DataFormatError(f"prune: expected a fraction in [0, 1), got {plain(prune)}")
    powers_max = _max_powers(max_power, names)
    order = whole_number(max_order, "max_order", DataFormatError, least=1)
    bars = (
        error_bars
        if error_bars is not None
        else ("colored" if isinstance(data, FlightData) else "white")
    )
    if bars not in ("white", "colored"):
        raise DataFormatError(f"error_bars: expected 'white' or 'colored', got {error_bars!r}")
    scale = np.max(np.abs(x), axis=0)
    for j in np.flatnonzero(np.ptp(x, axis=0) == 0).tolist():
        raise IdentificationError(f"variable {names[j]!r} is constant: it explains nothing")
    xs = x / scale  # powers of variables of order one keep the monomials well scaled
    generated = _generate(xs, z, powers_max, min(order, int(sum(powers_max))))
    bound = _noise_bound(noise_variance, z, xs)
    wanted = (
        None
        if n_functions is None
        else whole_number(n_functions, "n_functions", DataFormatError, least=1)
    )
    # the functions as generated (SIDPAC's offit), and again in the order of their effect
    # (Morelli; SIDPAC's mof): the one whose model the PSE prefers (`_by_effect`)
    choices = [_ranked(*generated, z, bound, wanted)]
    effect = _by_effect(xs, z, *generated)
    if effect[0].shape != generated[0].shape or not np.array_equal(effect[0], generated[0]):
        choices.append(_ranked(*effect, z, bound, wanted))
    mono, psi, norms, a, rank, pse_hist, keep = min(choices, key=lambda c: _final_pse(c, z, bound))
    if n <= keep:
        raise IdentificationError(f"orthogonal functions: {n} samples cannot fit {keep} functions")
    kept = rank[:keep]
    fitted_o = psi[:, kept] @ a[kept]
    v = z - fitted_o
    s2 = float(v @ v) / (n - keep)
    # each kept function written as the monomials generated up to it (exact: Gram-Schmidt)
    back = np.zeros((mono.shape[0], keep))
    basis = _monomials(xs, mono)
    for i, f in enumerate(kept.tolist()):
        coef, *_ = np.linalg.lstsq(basis[:, : f + 1], psi[:, f], rcond=None)
        back[: f + 1, i] = coef
    if bars == "colored":
        cov_a, nu = colored_covariance(
            [psi[:, kept][:, None, :]], [v[:, None]], np.diag(1 / norms[kept]), rcond=0.0
        )
    else:
        cov_a, nu = np.diag(s2 / norms[kept]), np.full(keep, float(n - keep))
    unscale = 1.0 / np.prod(scale[None, :] ** mono, axis=1)  # back to the variables' units
    coef_all = unscale * (back @ a[kept])
    cov_all = (unscale[:, None] * back) @ cov_a @ (unscale[:, None] * back).T
    used = np.flatnonzero(np.any(back != 0.0, axis=1))
    terms = _monomials(x, mono[used]) * coef_all[used]
    z_rms = float(np.sqrt(np.mean(z**2)))
    big = np.sqrt(np.mean(terms**2, axis=0)) > cut * z_rms if cut > 0 else np.ones(used.size, bool)
    used = used[big]
    coef, cov, powers = coef_all[used], cov_all[np.ix_(used, used)], mono[used]
    fitted = _monomials(x, powers) @ coef
    resid = z - fitted
    s2 = float(resid @ resid) / (n - keep)  # of the polynomial returned, pruned or not
    term_names = [_term_name(p, names) for p in powers]
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    zc = z - z.mean()
    sst = float(zc @ zc)
    dof_term = float(np.min(nu)) if nu.size else float(n - keep)
    return OrthogonalFunctionResult(
        parameters={t: float(c) for t, c in zip(term_names, coef, strict=True)},
        stderr={t: float(s) for t, s in zip(term_names, se, strict=True)},
        covariance=cov,
        parameter_names=tuple(term_names),
        powers=powers,
        variable_names=tuple(names),
        response_name=zname,
        n_functions=keep,
        pse_history=pse_hist,
        noise_bound=bound,
        pse=float(pse_hist[keep - 1]),
        r_squared=1.0 - float(resid @ resid) / sst if sst > 0 else float("nan"),
        fit_error=float(np.sqrt(s2)),
        response=z,
        fitted=fitted,
        residuals=resid,
        error_bars=bars,
        degrees_of_freedom=dict.fromkeys(term_names, dof_term),
    )


def _generate(
    xs: FloatArray, z: FloatArray, max_powers: list[int], max_order: int
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """The monomials' powers in generation order, their orthogonal functions and the
    functions' squared norms. Order by order: each monomial of the order below times
    each variable, within the powers, once, and left out where the data cannot tell
    it from those before it; stops when the fit is perfect."""
    n, k = xs.shape
    mono: list[tuple[int, ...]] = [(0,) * k]
    funcs = [np.ones(n)]
    seen = {mono[0]}
    level = [0]  # indices of the previous order's monomials
    z_rms = float(np.sqrt(np.mean(z**2))) or 1.0
    for _ in range(max_order):
        fit = _fit_rms(np.column_stack(funcs), z)
        if fit <= _PERFECT_FIT * z_rms:
            break
        nxt = []
        for parent, j in itertools.product(level, range(k)):
            powers = list(mono[parent])
            powers[j] += 1
            key = tuple(powers)
            if key in seen or powers[j] > max_powers[j]:
                continue
            seen.add(key)
            new = _new_direction(xs[:, j] * funcs[parent], funcs)
            if new is None:
                # the data cannot tell this monomial from those before it (too few
                # distinct values of a variable, or variables tied to each other): it
                # adds no direction to fit, nor a parent for the next order
                continue
            mono.append(key)
            funcs.append(new)
            nxt.append(len(mono) - 1)
        if not nxt:
            break
        level = nxt
    psi = np.column_stack(funcs)
    if psi.shape[1] >= n:
        raise IdentificationError(
            f"orthogonal functions: {psi.shape[1]} candidate functions for {n} samples; "
            "lower max_power or max_order"
        )
    return np.array(mono, dtype=np.int64), psi, np.einsum("ij,ij->j", psi, psi)


def _new_direction(column: FloatArray, funcs: list[FloatArray]) -> FloatArray | None:
    """`column` made orthogonal to `funcs` (Gram-Schmidt), or None when less than
    `_DEPENDENT` of it is left: the data cannot tell it from them."""
    new = column
    size = float(np.sqrt(new @ new))
    if funcs:
        basis = np.column_stack(funcs)
        norms = np.einsum("ij,ij->j", basis, basis)
        for _ in range(2):  # twice: one pass of Gram-Schmidt loses orthogonality
            new = new - basis @ ((basis.T @ new) / norms)
    return new if float(np.sqrt(new @ new)) > _DEPENDENT * size else None


def _orthogonal(
    xs: FloatArray, mono: NDArray[np.int64]
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """Gram-Schmidt of the monomials in the order given, leaving out those the data
    cannot tell from the ones before them."""
    raw = _monomials(xs, mono)
    keep: list[int] = []
    funcs: list[FloatArray] = []
    for i in range(mono.shape[0]):
        new = _new_direction(raw[:, i], funcs)
        if new is not None:
            keep.append(i)
            funcs.append(new)
    psi = np.column_stack(funcs)
    return mono[keep], psi, np.einsum("ij,ij->j", psi, psi)


def _by_effect(
    xs: FloatArray,
    z: FloatArray,
    mono: NDArray[np.int64],
    psi: FloatArray,
    norms: FloatArray,
) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
    """The functions generated again with their monomials in the order of their effect
    (Morelli; SIDPAC's ``mof`` re-generates once), the constant first: a function is
    then orthogonal only to the ones that fit more, so one the PSE leaves out does not
    take with it a share of a kept one. Generated in the order the variables happen to
    be listed, a weak ``b^2`` before a strong ``a^2`` left the kept ``a^2`` function
    carrying a ``b^2`` part that only the dropped one cancelled, and the model then
    depended on the order of `variables` (the true five terms 0 times in 100 with
    the variables swapped). Repeated until the order holds. Either order can give
    the better model (on SIDPAC's offit demo the generated one does), so both are
    ranked and the PSE of the polynomial each keeps picks (`_final_pse`)."""
    for _ in range(_REORDERINGS):
        effect = norms * ((psi.T @ z) / norms) ** 2
        order = np.concatenate([[0], 1 + np.argsort(-effect[1:], kind="stable")])
        if np.array_equal(order, np.arange(order.size)):
            break
        mono, psi, norms = _orthogonal(xs, mono[order])
    return mono, psi, norms


def _ranked(
    mono: NDArray[np.int64],
    psi: FloatArray,
    norms: FloatArray,
    z: FloatArray,
    bound: float,
    wanted: int | None,
) -> tuple[
    NDArray[np.int64], FloatArray, FloatArray, FloatArray, NDArray[np.intp], FloatArray, int
]:
    """The functions ranked by the fit error each takes away, the PSE with the first
    1, 2, ... of them, and how many are kept (the PSE's minimum, or `wanted`)."""
    n = z.size
    a = (psi.T @ z) / norms
    rank = np.argsort(-(norms * a**2), kind="stable")
    sse = np.maximum(float(z @ z) - np.cumsum((norms * a**2)[rank]), 0.0)
    pse_hist = sse / n + 2.0 * bound * np.arange(1, rank.size + 1) / n
    if wanted is None:
        keep = int(np.argmin(pse_hist)) + 1
    elif wanted > rank.size:
        raise DataFormatError(
            f"n_functions: {wanted} asked, {rank.size} orthogonal functions generated"
        )
    else:
        keep = wanted
    return mono, psi, norms, a, rank, pse_hist, keep


def _final_pse(choice: tuple[Any, ...], z: FloatArray, bound: float) -> float:
    """The PSE of the ordinary polynomial a ranking keeps, its penalty counting the
    polynomial's terms (a kept function is written with every monomial generated up to
    it: SIDPAC's ``npf``), so that of two orders fitting alike the one needing fewer
    terms wins."""
    _, _, norms, a, rank, _, keep = choice
    kept = rank[:keep]
    sse = max(float(z @ z) - float(np.sum((norms * a**2)[kept])), 0.0)
    return sse / z.size + 2.0 * bound * (int(np.max(kept)) + 1) / z.size


def _fit_rms(psi: FloatArray, z: FloatArray) -> float:
    coef, *_ = np.linalg.lstsq(psi, z, rcond=None)
    r = z - psi @ coef
    return float(np.sqrt(np.mean(r**2)))


def _monomials(x: FloatArray, powers: NDArray[np.int64]) -> FloatArray:
    """Columns ``prod_j x_j^powers[i, j]``, one per row of `powers`."""
    out = np.ones((x.shape[0], powers.shape[0]))
    for i, row in enumerate(powers):
        for j, pw in enumerate(row.tolist()):
            if pw:
                out[:, i] *= x[:, j] ** pw
    return out


def _term_name(powers: NDArray[np.int64], names: list[str]) -> str:
    parts = [n if p == 1 else f"{n}^{p}" for n, p in zip(names, powers.tolist(), strict=True) if p]
    return "*".join(parts) or "1"


def _noise_bound(value: float | str, z: FloatArray, xs: FloatArray) -> float:
    """``sigma2_max`` of the PSE from the `noise_variance` option."""
    n = z.size
    if isinstance(value, str):
        if value not in _NOISE_BOUNDS:
            raise DataFormatError(
                f"noise_variance: expected a number or one of {_NOISE_BOUNDS}, got {value!r}"
            )
        if value == "spread":
            zc = z - z.mean()
            return float(zc @ zc) / (2.0 * n)
        lin = np.column_stack([np.ones(n), xs])
        coef, *_ = np.linalg.lstsq(lin, z, rcond=None)
        r = z - lin @ coef
        return 4.0 * float(r @ r) / max(n - lin.shape[1], 1)
    v = as_float(value)
    if v is None or not (np.isfinite(v) and v > 0.0):
        raise DataFormatError(
            f"noise_variance: expected a positive variance or one of {_NOISE_BOUNDS}, "
            f"got {plain(value)}"
        )
    return 25.0 * v


def _max_powers(value: Any, names: list[str]) -> list[int]:
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise DataFormatError(f"max_power: {unknown} are not among the variables {names}")
        missing = [n for n in names if n not in value]
        if missing:
            # silently 0 would leave a listed variable out of every term
            raise DataFormatError(
                f"max_power: no power given for {missing}; name every variable of "
                f"{names} (0 leaves one out)"
            )
        out = [whole_number(value[n], f"max_power[{n!r}]", DataFormatError, least=0) for n in names]
    elif isinstance(value, Sequence) and not isinstance(value, str):
        if len(value) != len(names):
            raise DataFormatError(
                f"max_power: expected one per variable ({len(names)}), got {len(value)}"
            )
        out = [
            whole_number(v, f"max_power[{i}]", DataFormatError, least=0)
            for i, v in enumerate(value)
        ]
    else:
        out = [whole_number(value, "max_power", DataFormatError, least=0)] * len(names)
    for n, p in zip(names, out, strict=True):
        if p > 8:
            raise DataFormatError(f"max_power[{n!r}]: at most 8, got {p}")
    return out
