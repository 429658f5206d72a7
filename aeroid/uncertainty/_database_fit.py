"""One coefficient of the aerodynamic database: random-effects meta-regression with
structure selection and model averaging (the method is argued in `aeroid.uncertainty.database`).

Every function here works on one coefficient's estimates ``z`` (n flights), their
stated variances ``v`` and the scaled conditions ``u`` of those flights.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState
from ..errors import IdentificationError

FloatArray = NDArray[np.float64]
Exponents = tuple[int, ...]

# models whose Akaike weight falls below this leave the average (their share of the
# band is below a part in a thousand of its variance)
_MIN_WEIGHT = 1e-3
# functions the model average looks at beyond the selected structure
_BEYOND = 2


def legendre(u: FloatArray, n: int) -> FloatArray:
    """The Legendre polynomial ``P_n(u)`` by its three-term recurrence."""
    p0, p1 = np.ones_like(u), u
    if n == 0:
        return p0
    for k in range(1, n):
        p0, p1 = p1, ((2 * k + 1) * u * p1 - k * p0) / (k + 1)
    return p1


def design(u: FloatArray, exponents: Sequence[Exponents]) -> FloatArray:
    """Columns ``Π_i P_{e_i}(u_i)``, one per exponent tuple."""
    cols = []
    for e in exponents:
        col = np.ones(u.shape[0])
        for i, n in enumerate(e):
            if n:
                col = col * legendre(u[:, i], n)
        cols.append(col)
    return np.stack(cols, axis=1)


def scaled(
    x: FloatArray, keys: Sequence[str], centres: Mapping[str, float], half: Mapping[str, float]
) -> FloatArray:
    """Condition rows `x` (columns `keys`) scaled to ``u = (x − centre) / half``."""
    c = np.array([centres[k] for k in keys])
    h = np.array([half[k] for k in keys])
    return np.asarray((x - c) / h, dtype=np.float64)


def label(e: Exponents, keys: Sequence[str]) -> str:
    """A basis function's label, ``"1"`` or ``"P1(alpha)*P2(mach)"``."""
    parts = [f"P{n}({k})" for n, k in zip(e, keys, strict=True) if n]
    return "*".join(parts) if parts else "1"


def parse_label(given: str, keys: Sequence[str], term: str) -> Exponents:
    """``"1"``, ``"alpha"``, ``"alpha^2"``, ``"alpha*mach"`` or ``"P2(alpha)"`` as exponents."""
    e = [0] * len(keys)
    text = given.replace(" ", "").replace("**", "^")
    if text in ("1", "const", "0"):
        return tuple(e)
    for part in text.split("*"):
        name, n = part, 1
        if part.startswith("P") and "(" in part and part.endswith(")"):
            n = int(part[1 : part.index("(")])
            name = part[part.index("(") + 1 : -1]
        elif "^" in part:
            name, power = part.split("^", 1)
            n = int(power)
        if name not in keys:
            raise IdentificationError(
                f"structure of {term!r} uses {name!r}, not a condition key ({', '.join(keys)})"
            )
        e[list(keys).index(name)] += n
    return tuple(e)


def candidate_exponents(n_keys: int, max_degree: int, varying: Sequence[bool]) -> list[Exponents]:
    """Every product of Legendre degrees up to `max_degree` in total over the keys that
    vary, lowest total degree first (the constant apart)."""
    out: list[Exponents] = []

    def grow(prefix: list[int], left: int) -> None:
        if len(prefix) == n_keys:
            out.append(tuple(prefix))
            return
        i = len(prefix)
        for n in range(0, (left if varying[i] else 0) + 1):
            grow([*prefix, n], left - n)

    grow([], max_degree)
    return sorted((e for e in out if any(e)), key=lambda e: (sum(e), e))


def parents(e: Exponents) -> list[Exponents]:
    """Hierarchy: each key's degree lowered by one (a product needs its factors)."""
    out = []
    for i, n in enumerate(e):
        if n:
            p = list(e)
            p[i] -= 1
            out.append(tuple(p))
    return out


def _with_ancestors(e: Exponents, chosen: Sequence[Exponents]) -> list[Exponents]:
    """`e` with every ancestor hierarchy asks for that `chosen` lacks, lowest degree first
    (the constant is always in)."""
    out: set[Exponents] = set()
    todo = [e]
    while todo:
        f = todo.pop()
        if f in out or f in chosen or not any(f):
            continue
        out.add(f)
        todo.extend(parents(f))
    return sorted(out, key=lambda f: (sum(f), f))


def _gls(a: FloatArray, z: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Weighted least squares by QR: the parameters, the gain ``(X'WX)⁻¹X'W`` and
    ``(X'WX)⁻¹``."""
    sw = np.sqrt(w)
    q, r = np.linalg.qr(a * sw[:, None])
    gain = np.linalg.solve(r, q.T * sw[None, :])
    r_inv = np.linalg.inv(r)
    return gain @ z, gain, r_inv @ r_inv.T


def _neg_loglik(a: FloatArray, z: FloatArray, v: FloatArray, tau2: float, reml: bool) -> float:
    """-2 log likelihood (constants dropped) of ``z ~ N(Xθ, diag(v + τ²))`` at the GLS θ;
    restricted (REML) when `reml`."""
    total = v + tau2
    sw = 1.0 / np.sqrt(total)
    q, r = np.linalg.qr(a * sw[:, None])
    b = z * sw
    resid = b - q @ (q.T @ b)  # the whitened residual of the GLS fit
    out = float(np.sum(np.log(total)) + resid @ resid)
    if reml:
        out += 2.0 * float(np.sum(np.log(np.abs(np.diag(r)))))  # log det X'WX
    return out


def between_variance(a: FloatArray, z: FloatArray, v: FloatArray, *, reml: bool = True) -> float:
    """The between-flight variance ``τ²`` by (restricted) maximum likelihood, >= 0.

    A golden-section search on ``τ`` over ``[0, τ_max]``, ``τ_max`` three times the
    scatter of the estimates (the likelihood is flat in ``τ`` beyond it), and the
    boundary ``τ = 0`` compared on its own (the optimum sits there whenever the stated
    variances explain the scatter).
    """
    n, p = a.shape
    if n - p < 1:
        return 0.0
    top = 3.0 * float(np.std(z)) + 3.0 * math.sqrt(float(np.max(v)))

    def f(t: float) -> float:
        return _neg_loglik(a, z, v, t * t, reml)

    lo, hi = 0.0, top
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(60):
        if hi - lo <= 1e-4 * top:
            break
        if f1 <= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = f(x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = f(x2)
    t = 0.5 * (lo + hi)
    return 0.0 if f(0.0) <= f(t) else t * t


def _independent(u: FloatArray, es: Sequence[Exponents]) -> list[Exponents]:
    """`es` in order, less each function the ones before it already span at the flights'
    conditions (three altitudes offer no cubic in altitude)."""
    kept: list[Exponents] = []
    for e in es:
        a = design(u, [*kept, e])
        if np.linalg.matrix_rank(
            a, tol=1e-10 * max(1.0, float(np.abs(a).max())) * a.shape[0]
        ) > len(kept):
            kept.append(e)
    return kept


@dataclass(frozen=True)
class ModelFit(FrozenState):
    """One structure fitted with its between-flight variance."""

    exponents: tuple[Exponents, ...]
    theta: FloatArray
    gain: FloatArray  # (p, n): parameters from the estimates
    covariance: FloatArray  # Knapp-Hartung scaled (X'WX)⁻¹
    tau2: float
    scale: float  # the Knapp-Hartung factor max(1, q)
    chi2: float  # Σ r² / (v + τ²)
    aicc: float


def fit_model(u: FloatArray, z: FloatArray, v: FloatArray, es: Sequence[Exponents]) -> ModelFit:
    """`es` fitted by REML random-effects weighted least squares with the Knapp-Hartung
    variance; its AICc from the maximum-likelihood fit."""
    a = design(u, es)
    n, p = a.shape
    tau2 = between_variance(a, z, v)
    w = 1.0 / (v + tau2)
    theta, gain, cov = _gls(a, z, w)
    r = z - a @ theta
    chi2 = float(np.sum(w * r * r))
    scale = max(1.0, chi2 / (n - p)) if n > p else 1.0
    k = p + 1  # and τ
    tau2_ml = between_variance(a, z, v, reml=False)
    m2ll = _neg_loglik(a, z, v, tau2_ml, False) + n * math.log(2.0 * math.pi)
    aicc = m2ll + 2 * k + (2 * k * (k + 1) / (n - k - 1) if n - k - 1 > 0 else math.inf)
    return ModelFit(tuple(es), theta, gain, cov * scale, tau2, scale, chi2, aicc)


def _tail(chi2: float, c2: float, q: int, dof: int) -> float:
    """The upper tail probability of the partial F of `q` functions that take the
    whitened residual sum of squares from `chi2` to `c2`, `dof` left (the weights are a
    floor on the scatter); with ``c2 = 0`` and ``q = 1``, that of ``F = chi2``."""
    from scipy.special import fdtrc

    s2 = max(c2 / dof, 1.0) if c2 > 0 else 1.0
    return float(fdtrc(q, dof, max(chi2 - c2, 0.0) / q / s2))


def forward_path(
    u: FloatArray, z: FloatArray, v: FloatArray, candidates: list[Exponents], f_in: float
) -> tuple[list[list[Exponents]], int]:
    """Klein & Morelli's forward stepwise order on weights ``1/(v + τ²)``, ``τ²`` of the
    richest candidate model; the nested models along it (while three flights are left
    over, up to `_BEYOND` functions past the selection), and the index of the one the
    partial F and the PSE select."""
    n = z.size
    chosen: list[Exponents] = [tuple(0 for _ in range(u.shape[1]))]
    full = _independent(u, [*chosen, *candidates])
    tau2 = between_variance(design(u, full), z, v) if n - len(full) >= 2 else 0.0
    w = 1.0 / (v + tau2)
    sw = np.sqrt(w)
    cols = {e: design(u, [e])[:, 0] * sw for e in [*chosen, *candidates]}
    b = z * sw

    def chi2_of(es: list[Exponents]) -> float:
        a = np.stack([cols[e] for e in es], axis=1)
        theta, _, rank, _ = np.linalg.lstsq(a, b, rcond=1e-10)
        if rank < len(es):
            return math.inf  # a function the flights' conditions cannot tell from the others
        r = b - a @ theta
        return float(r @ r)

    chi2 = chi2_of(chosen)
    # the whitened noise variance is 1 if the weights hold; the richest model's
    # residual variance bounds it from above when they do not
    s2_max = max(1.0, chi2_of(full) / (n - len(full))) if n > len(full) else 1.0
    pse = chi2 / n + s2_max / n
    path, selected, stopped = [list(chosen)], 0, False
    # a step adds a candidate with the factors hierarchy asks for, so a product whose
    # factors explain nothing alone (an effect of Mach that reverses with alpha) can
    # still enter. The candidate itself must earn the step: ranked and tested by its
    # own partial F given the others (one degree of freedom, `f_in`'s level), and the
    # factors it brings with it must pass with it (the step's F on all it adds)
    offered = set(candidates)
    # past the selected model, two more steps: the F test rejected the first, and the
    # Akaike weights of richer models are then below a part in a thousand
    while n - len(chosen) > 3 and len(path) - selected <= _BEYOND:
        steps: list[tuple[tuple[float, int, float], float, list[Exponents]]] = []
        tried: set[tuple[Exponents, ...]] = set()
        for e in candidates:
            if e in chosen:
                continue
            move = _with_ancestors(e, chosen)
            if tuple(move) in tried or not offered.issuperset(move):
                continue
            tried.add(tuple(move))
            p = len(chosen) + len(move)
            if n - p < 2:
                continue
            c2 = chi2_of([*chosen, *move])
            factors = [f for f in move if f != e]
            before = chi2_of([*chosen, *factors]) if factors else chi2
            if not (math.isfinite(c2) and math.isfinite(before)):
                continue
            # ties (tails below the smallest float) go to the smaller step
            key = (_tail(before, c2, 1, n - p), len(move), c2)
            steps.append((key, _tail(chi2, c2, len(move), n - p), move))
        if not steps:
            break
        # the steps hierarchy alone used to bar are extra chances for noise to enter:
        # Bonferroni over them keeps what they add to the false entries below the level
        several = max(1, sum(1 for _, _, m in steps if len(m) > 1))
        good = []
        for step in steps:
            (own, size, _), whole, _ = step
            level = _tail(f_in, 0.0, 1, n - len(chosen) - size)
            if max(own, whole) <= (level if size == 1 else level / several):
                good.append(step)
        best = min(good or steps, key=lambda step: step[0])
        (_, _, c2), _, move = best
        p = len(chosen) + len(move)
        new_pse = c2 / n + s2_max * p / n
        if not stopped and (not good or new_pse >= pse):
            stopped = True
        chosen.extend(move)
        path.append(list(chosen))
        if not stopped:
            selected, pse = len(path) - 1, new_pse
        chi2 = c2
    return path, selected


@dataclass(frozen=True)
class TermFit(FrozenState):
    """A coefficient's database entry: the model average over its basis."""

    exponents: tuple[Exponents, ...]  # the basis of the average (the richest model kept)
    selected: tuple[Exponents, ...]  # the structure stepwise regression selects
    theta: FloatArray
    gain: FloatArray  # (p, n)
    covariance: FloatArray
    tau2: float
    scale: float
    chi2: float
    dof: float
    weights: tuple[float, ...]  # Akaike weight of each model averaged, along the path


def _padded(fit: ModelFit, basis: Sequence[Exponents]) -> tuple[FloatArray, FloatArray, FloatArray]:
    idx = [basis.index(e) for e in fit.exponents]
    p = len(basis)
    theta = np.zeros(p)
    theta[idx] = fit.theta
    gain = np.zeros((p, fit.gain.shape[1]))
    gain[idx] = fit.gain
    cov = np.zeros((p, p))
    cov[np.ix_(idx, idx)] = fit.covariance
    return theta, gain, cov


def fit_term(
    u: FloatArray,
    z: FloatArray,
    v: FloatArray,
    *,
    candidates: list[Exponents] | None = None,
    forced: Sequence[Exponents] | None = None,
    f_in: float = 4.0,
) -> TermFit:
    """One coefficient: a forced structure on its own, else the Akaike-weighted average
    of the models along the forward path (Buckland et al. 1997; Burnham & Anderson
    2002, eq. 4.9: the unconditional covariance adds each model's spread about the
    average to its own)."""
    if forced is not None:
        path, selected = [list(forced)], 0
    else:
        path, selected = forward_path(u, z, v, list(candidates or []), f_in)
    fits = [fit_model(u, z, v, es) for es in path]
    aicc = np.array([f.aicc for f in fits])
    if not np.isfinite(aicc).any():
        fits, aicc = [fits[selected]], np.zeros(1)
        selected = 0
    w = np.exp(-0.5 * (aicc - np.min(aicc)))
    w = np.where(np.isfinite(w), w, 0.0)
    w /= w.sum()
    keep = [i for i in range(len(fits)) if w[i] >= _MIN_WEIGHT]
    fits = [fits[i] for i in keep]
    w = w[keep] / w[keep].sum()
    basis = max((f.exponents for f in fits), key=len)  # nested: the richest holds them all
    parts = [_padded(f, basis) for f in fits]
    theta = sum((wi * p[0] for wi, p in zip(w, parts, strict=True)), np.zeros(len(basis)))
    gain = sum((wi * p[1] for wi, p in zip(w, parts, strict=True)), np.zeros_like(parts[0][1]))
    cov = np.zeros((len(basis), len(basis)))
    for wi, (th, _, c) in zip(w, parts, strict=True):
        d = th - theta
        cov += wi * (c + np.outer(d, d))
    best = fits[int(np.argmax(w))]
    n = z.size
    return TermFit(
        exponents=tuple(basis),
        selected=tuple(path[selected]),
        theta=theta,
        gain=gain,
        covariance=0.5 * (cov + cov.T),
        tau2=float(np.sum(w * np.array([f.tau2 for f in fits]))),
        scale=best.scale,
        chi2=best.chi2,
        dof=float(n - len(best.exponents)),
        weights=tuple(float(x) for x in w),
    )
