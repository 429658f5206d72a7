"""The aerodynamic database: coefficients as smooth functions of the flight condition.

A campaign identifies each manoeuvre on its own, at its own flight condition
(airspeed, altitude, angle of attack, Mach, ...). `aerodynamic_database`
stitches the per-flight estimates into one model per coefficient,
``c_j(x) = Σ_k θ_jk φ_k(x)``, fitted jointly over all flights.

Why a weighted global regression of the per-flight estimates
--------------------------------------------------------------
Klein & Morelli (ch. 5, "global" modelling; SIDPAC's stepwise and PSE tools)
fit a global model by regressing local estimates on the flight condition. The
alternative, one multi-flight output error over every record, refits every
flight whenever one is added and ties the database to the dynamic model of
the campaign. The regression of the estimates costs milliseconds, leaves each
flight's task untouched (a campaign adding one flight recomputes that flight
and this fit, nothing else) and carries each flight's full parameter
covariance. Each coefficient ``j`` is fitted on its own estimates ``z_fj`` with the basis
rows ``X_j`` at the flights' conditions.

Why random effects
------------------
A flight's covariance (Cramér-Rao, or its sandwich) states only the error the
noise it models leaves; each flight also carries errors it does not state:
model structure (an unmodelled effect or nonlinearity, lumped terms), coloured
residuals, the pilot's corrections, its own turbulence. They differ from flight
to flight, so the estimates scatter about the smooth surface by more than their
error bars, and the flights with the tightest bars, no less biased, would
dominate a fit weighted by the bars alone (the fixed-effect fit; its Birge
factor widens the band but keeps those weights). The meta-analysis of studies
with unequal, understated errors has the same structure and its answer is the
random-effects meta-regression (DerSimonian & Laird 1986; Raudenbush 2009;
Viechtbauer 2005 for the REML estimator):

    z_fj = x_f' θ_j + b_fj + e_fj,   b_fj ~ N(0, τ_j²),   e_fj ~ N(0, v_fj),

``τ_j²`` the between-flight variance of coefficient ``j``, estimated by
restricted maximum likelihood (zero when the stated variances explain the
scatter, and then the fit is the fixed-effect one), and the weights
``1/(v_fj + τ_j²)``:

    θ_j = G_j z_j,   G_j = (X_j' W_j X_j)⁻¹ X_j' W_j,   W_j = diag(1 / (v_fj + τ_j²)),

solved through a QR factorisation of the weighted rows. With the dozen flights
of a campaign the normal quantile understates the band: the Knapp-Hartung
(Hartung-Knapp-Sidik-Jonkman) variance, ``(X'WX)⁻¹`` scaled by
``max(1, Σ w r² / (n − p))``, and Student's t quantile on ``n − p`` degrees of
freedom keep the coverage near nominal for few studies (Knapp & Hartung 2003;
Röver, Knapp & Friede 2015 for the ``max(1, ·)``). Not a joint generalised
least squares over every coefficient with the full per-flight covariances: on
real flights the coefficients of one flight share its errors (Cl_p with
Cl_delta_a through the roll response, a bias from an unmodelled effect in all
of them), and the joint fit then moves each mean by the residuals of the
others, out of the range of every flight's estimate where the flights share a
bias (Peelle's puzzle; the demo's twelve c172x flights put a joint Cl_p below
all twelve estimates). The correlations are kept where they belong, in the
covariance of the database: with ``V_f`` flight ``f``'s full covariance and
``g_jf`` column ``f`` of ``G_j``,

    Cov(θ_j, θ_k) = Σ_f g_jf V_f,jk g_kf'   (j ≠ k),

the covariance of these linear estimates (the sandwich), so a band on a sum of
coefficients (CL_0 + CL_alpha α) counts their correlation.

What no fit of the estimates can see is an error all flights share (the same
model-structure bias in every identification): it moves the surface without
scattering the flights about it, and it belongs to each flight's
identification. `tests/reference/c172x_demo_database.py` separates the two on
the demo campaign (each flight's own interval against the simulator's value).

Basis, structure selection and model averaging
----------------------------------------------
Each condition key is scaled to ``u ∈ [-1, 1]`` over the fitted flights and
the candidates are products of Legendre polynomials ``P_n(u)`` of total degree
at most `max_degree`: orthogonal over the flown box, so the columns stay well
conditioned where raw powers of alpha in radians would not. The structure of
each coefficient is chosen by forward stepwise regression on its whitened
estimates (weights ``1/(v + τ²)``, ``τ²`` of the richest candidate model) as in
Klein & Morelli ch. 5: a candidate enters when its partial F exceeds `f_in`
(default 4, about 95 % significance for one term) *and* the predicted squared
error ``PSE = χ²/N + σ²_max p/N`` decreases. Klein & Morelli's ``σ²_max``
bounds the noise variance from above; for whitened estimates that variance is
1 when the weights hold, so ``σ²_max`` is the larger of 1 and the residual
variance of the richest candidate model. Models respect hierarchy (``P_2(u)``
needs ``P_1(u)``, a product both factors): a candidate enters with the factors
it lacks, on its own partial F and theirs together (Bonferroni over such steps),
so an effect of Mach that reverses with alpha enters where Mach alone explains
nothing. A key that does not vary over the flights offering a coefficient
offers it no candidate, nor does a function the flights' conditions cannot tell
from those before it.

A band drawn from the selected structure alone is conditional on a choice
made from the same data, and narrower than its error (a curvature the F test
just missed is a bias the band does not hold). The database therefore averages
the models along the stepwise path (the selected one, its predecessors and
two richer ones) with their Akaike weights (AICc of the maximum-likelihood
fit), and the band is the unconditional one of Buckland, Burnham & Augustin
(1997) and Burnham & Anderson (2002, eq. 4.9): each model's covariance plus its
spread about the average, ``Σ_m w_m [C_m + (θ_m − θ̄)(θ_m − θ̄)']``. The
structures stay nested, so the average is one model in the richest basis kept
(`basis`); `structures` names the selected one. A structure can also be forced
per coefficient with `structures` (then no average).

Uncertainty
-----------
A band at a condition ``x`` is ``c(x) ± t σ(x)`` with ``σ²(x) = φ(x)' Cov θ_j
φ(x)`` and ``t`` Student's quantile on the term's `dof`.

Speed terms (``Cm_V``: a model's regressor ``V/V0 − 1`` about each flight's own
trim speed) fly about the trim speed over the condition keys, fitted to the
flights' trim speeds: `aeroid.uncertainty._database_speed` argues the reference.

Held-out check
--------------
Flights named in `held_out` stay out of the fit; their estimates are compared
with the database's prediction, ``(z − c(x)) / sqrt(σ_z² + τ² + σ²(x))`` (a new
flight scatters by ``τ`` too), inside when within the band's quantile.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._records import FrozenState, ReadOnlyDict, fmt, frozen_array, frozen_mapping, markdown_table
from .._stats import norm_ppf
from ..errors import DataFormatError, IdentificationError
from ._database_checks import (
    check_identifiable,
    condition_rows,
    database_options,
    diagonal,
    flight_values,
    grid_points,
    key_list,
    keys_and_terms,
    t_quantile,
)
from ._database_fit import (
    TermFit,
    candidate_exponents,
    design,
    fit_term,
    label,
    parse_label,
    scaled,
)
from ._database_speed import TrimSpeedModel, fit_trim_speed, is_speed_term

__all__ = [
    "AeroDatabase",
    "FlightCoefficients",
    "HeldOutCheck",
    "TrimSpeedModel",
    "aerodynamic_database",
    "is_speed_term",
]

FloatArray = NDArray[np.float64]
Exponents = tuple[int, ...]


@dataclass(frozen=True, eq=False)
class FlightCoefficients(FrozenState):
    """One flight's coefficient estimates at its flight condition.

    Attributes
    ----------
    name : str
        The flight, named in every message and table.
    condition : mapping of str to float
        Flight condition keys (airspeed, altitude, alpha, mach, ...).
    estimates : mapping of str to float
        Coefficient estimates by name (``CL_alpha``, ``Cm_q``, ...); NaN
        marks a coefficient this flight did not excite.
    covariance : ndarray, shape (n, n)
        Covariance of the estimates in the order of `estimates`.
    trim_speed : float, optional
        The trim speed ``V0`` (m/s) the flight's speed regressor ``V/V0 − 1`` refers
        to (its speed terms ``CL_V``, ``Cm_V``, ...); default the condition's
        ``airspeed``.
    """

    name: str
    condition: Mapping[str, float]
    estimates: Mapping[str, float]
    covariance: FloatArray
    trim_speed: float | None = None

    def __post_init__(self) -> None:
        if self.trim_speed is None:
            # the condition's airspeed where it is one (a flight without speed terms
            # needs none, and a bad airspeed key is named where a fit uses it)
            try:
                v = float(self.condition.get("airspeed", math.nan))
            except (TypeError, ValueError):
                v = math.nan
            object.__setattr__(self, "trim_speed", v if math.isfinite(v) and v > 0.0 else None)
        else:
            v0 = float(self.trim_speed)
            if not (math.isfinite(v0) and v0 > 0.0):
                raise DataFormatError(f"flight {self.name!r}: trim speed {v0} is not positive")
            object.__setattr__(self, "trim_speed", v0)
        object.__setattr__(self, "name", str(self.name))
        condition, estimates, cov = flight_values(
            self.name, self.condition, self.estimates, self.covariance
        )
        object.__setattr__(self, "condition", frozen_mapping(condition))
        object.__setattr__(self, "estimates", frozen_mapping(estimates))
        object.__setattr__(self, "covariance", frozen_array(cov))

    @classmethod
    def from_stderr(
        cls,
        name: str,
        condition: Mapping[str, float],
        estimates: Mapping[str, float],
        stderr: Mapping[str, float],
        *,
        trim_speed: float | None = None,
    ) -> FlightCoefficients:
        """Estimates with independent standard errors (a diagonal covariance)."""
        return cls(name, condition, estimates, diagonal(name, estimates, stderr), trim_speed)


@dataclass(frozen=True, eq=False)
class HeldOutCheck(FrozenState):
    """A held-out flight's estimate against the database's prediction.

    Attributes
    ----------
    flight, term : str
    estimate, stderr : float
        The flight's own estimate and standard error.
    prediction, band_stderr : float
        The database at the flight's condition and its standard error.
    z : float
        ``(estimate − prediction) / sqrt(stderr² + τ² + band_stderr²)``, ``τ²`` the
        term's between-flight variance (a new flight scatters by it too).
    limit : float
        The quantile `z` is compared with at the database's confidence (Student's t
        on the term's degrees of freedom).
    """

    flight: str
    term: str
    estimate: float
    stderr: float
    prediction: float
    band_stderr: float
    z: float
    limit: float = 1.959963984540054

    @property
    def inside(self) -> bool:
        """Whether the estimate lies inside the database's prediction band."""
        return abs(self.z) <= self.limit


@dataclass(frozen=True, eq=False)
class AeroDatabase(FrozenState):
    """Coefficients as functions of the flight condition, with covariance.

    Attributes
    ----------
    terms : tuple of str
        The coefficients modelled.
    keys : tuple of str
        Condition keys, in the order `predict` takes them.
    centres, half_ranges : mapping of str to float
        The scaling ``u = (x − centre) / half_range`` of each key over the fitted
        flights (half range 1 for a key that did not vary).
    structures : mapping of str to tuple of str
        The structure stepwise regression selects for each coefficient, as labels
        (``"1"``, ``"P1(alpha)"``, ``"P1(alpha)*P1(mach)"``).
    parameters : mapping of str to ndarray
        Coefficients of the basis functions of `basis`, per term (the model average).
    covariance : ndarray
        Joint covariance of all basis coefficients, terms in order `terms`.
    scale : mapping of str to float
        The Knapp-Hartung factor ``max(1, χ²/dof)`` applied to each term's block.
    chi2, dof : mapping of str to float
        Weighted residual sum of squares (weights ``1/(v + τ²)``) and its degrees of
        freedom per term, of the model with the largest weight; `dof` sets the
        Student's t quantile of the bands.
    flights : tuple of str
        Flights in the fit.
    conditions : ndarray, shape (n_flights, n_keys)
    estimates, stderr : ndarray, shape (n_flights, n_terms)
        The per-flight data (NaN where a flight did not excite a term).
    held_out : tuple of HeldOutCheck
    confidence : float
        Level of the bands of `band` and the held-out coverage.
    tau2 : mapping of str to float
        Between-flight variance of each coefficient (REML; module notes).
    basis : mapping of str to tuple of str
        The basis of each coefficient's model average (`structures` and the richer
        models along the stepwise path that keep an Akaike weight).
    speed_reference : TrimSpeedModel or None
        The trim speed ``V0`` over the keys that the speed terms (``Cm_V``) refer to:
        such a term flies as ``C_V (V/V0 − 1)`` (`aeroid.uncertainty._database_speed`);
        None without one.
    """

    terms: tuple[str, ...]
    keys: tuple[str, ...]
    centres: Mapping[str, float]
    half_ranges: Mapping[str, float]
    structures: Mapping[str, tuple[str, ...]]
    parameters: Mapping[str, FloatArray]
    covariance: FloatArray
    scale: Mapping[str, float]
    chi2: Mapping[str, float]
    dof: Mapping[str, float]
    flights: tuple[str, ...]
    conditions: FloatArray
    estimates: FloatArray
    stderr: FloatArray
    held_out: tuple[HeldOutCheck, ...] = ()
    confidence: float = 0.95
    tau2: Mapping[str, float] = field(default_factory=dict)
    basis: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    speed_reference: TrimSpeedModel | None = None
    _exponents: Mapping[str, tuple[Exponents, ...]] = field(default_factory=dict, repr=False)
    _offsets: Mapping[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        names = ("centres", "half_ranges", "structures", "scale", "chi2", "dof", "tau2", "basis")
        for name in names:
            object.__setattr__(self, name, frozen_mapping(getattr(self, name)))
        object.__setattr__(
            self,
            "parameters",
            frozen_mapping({k: frozen_array(v) for k, v in self.parameters.items()}),
        )
        for name in ("covariance", "conditions", "estimates", "stderr"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        exps = {t: tuple(tuple(int(n) for n in e) for e in es) for t, es in self._exponents.items()}
        object.__setattr__(self, "_exponents", ReadOnlyDict(exps))
        object.__setattr__(
            self, "_offsets", ReadOnlyDict({k: int(v) for k, v in self._offsets.items()})
        )
        object.__setattr__(self, "held_out", tuple(self.held_out))

    # -- evaluation ---------------------------------------------------------------------------

    def _basis(self, term: str, condition: Mapping[str, ArrayLike] | ArrayLike) -> FloatArray:
        if term not in self.parameters:
            raise IdentificationError(
                f"the database has no term {term!r}; it models {', '.join(self.terms)}"
            )
        return design(self._scaled_condition(term, condition), self._exponents[term])

    def _scaled_condition(
        self, term: str, condition: Mapping[str, ArrayLike] | ArrayLike
    ) -> FloatArray:
        x = condition_rows(term, self.keys, condition)
        return scaled(x, self.keys, self.centres, self.half_ranges)

    @property
    def speed_terms(self) -> tuple[str, ...]:
        """The speed terms (``<C>_V``), which fly as ``C_V (V/V0 − 1)``."""
        return tuple(t for t in self.terms if is_speed_term(t))

    def trim_speed(
        self, condition: Mapping[str, ArrayLike] | ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """The trim speed ``V0`` (m/s) the speed terms refer to, and its standard error.

        Parameters
        ----------
        condition : mapping of str to array_like, or array_like (n, n_keys)
            As for `predict`.

        Returns
        -------
        value, stderr : ndarray, shape (n,)
        """
        if self.speed_reference is None:
            raise IdentificationError(
                "the database has no speed term (<C>_V), so no trim-speed reference"
            )
        return self.speed_reference.evaluate(self._scaled_condition("V0", condition))

    def predict(
        self, term: str, condition: Mapping[str, ArrayLike] | ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """The coefficient and its standard error at one or more conditions.

        Parameters
        ----------
        term : str
            A coefficient of `terms`.
        condition : mapping of str to array_like, or array_like (n, n_keys)
            Condition keys (arrays broadcast), or rows in the order of `keys`.

        Returns
        -------
        value, stderr : ndarray, shape (n,)

        Warns
        -----
        UserWarning
            At a condition outside the flown `envelope`, naming the key: the
            polynomials extrapolate there, and their band says nothing of it.
        """
        return self._predict(term, condition, warn=True)

    @property
    def envelope(self) -> dict[str, tuple[float, float]]:
        """Each condition key's range over the fitted flights (where `predict` interpolates)."""
        return {
            k: (float(np.min(self.conditions[:, j])), float(np.max(self.conditions[:, j])))
            for j, k in enumerate(self.keys)
        }

    def _predict(
        self, term: str, condition: Mapping[str, ArrayLike] | ArrayLike, *, warn: bool
    ) -> tuple[FloatArray, FloatArray]:
        phi = self._basis(term, condition)
        if warn and self.conditions.size:
            x = condition_rows(term, self.keys, condition)
            for j, (k, (lo, hi)) in enumerate(self.envelope.items()):
                slack = 1e-9 * max(hi - lo, abs(hi), abs(lo), 1e-300)
                away = x[:, j][(x[:, j] < lo - slack) | (x[:, j] > hi + slack)]
                if away.size:
                    warnings.warn(
                        f"{term}: {k} = {away[0]:.6g} lies outside the flown envelope "
                        f"[{lo:.6g}, {hi:.6g}]; the database extrapolates there",
                        UserWarning,
                        stacklevel=3,  # here, predict or band, their caller
                    )
                    break
        j0 = self._offsets[term]
        theta = self.parameters[term]
        block = self.covariance[j0 : j0 + theta.size, j0 : j0 + theta.size]
        value = phi @ theta
        var = np.einsum("ij,jk,ik->i", phi, block, phi)
        return value, np.sqrt(np.maximum(var, 0.0))

    def band(
        self,
        term: str,
        condition: Mapping[str, ArrayLike] | ArrayLike,
        *,
        confidence: float | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Prediction with its lower and upper confidence bound (default `confidence`):
        ``± t σ``, ``t`` Student's quantile on the term's `dof` (Knapp-Hartung)."""
        level = self.confidence if confidence is None else float(confidence)
        if not 0.0 < level < 1.0:
            raise IdentificationError(f"confidence must lie in (0, 1), got {level}")
        value, se = self._predict(term, condition, warn=True)
        z = self.quantile(term, level)
        return value, value - z * se, value + z * se

    def quantile(self, term: str, confidence: float | None = None) -> float:
        """The two-sided quantile of `term`'s bands: Student's t on its `dof`."""
        level = self.confidence if confidence is None else float(confidence)
        return t_quantile(self.dof.get(term, 0.0), 0.5 + 0.5 * level)

    def as_function(self) -> Callable[..., dict[str, FloatArray]]:
        """A plain callable ``f(**condition) -> {term: value}`` for a simulation.

        With speed terms it also returns ``"V0"``, the trim speed (m/s) they refer
        to: a speed term ``C_V`` adds ``C_V (V/V0 − 1)`` at airspeed ``V``."""

        def evaluate(**condition: ArrayLike) -> dict[str, FloatArray]:
            out = {t: self.predict(t, condition)[0] for t in self.terms}
            if self.speed_reference is not None:
                out["V0"] = self.trim_speed(condition)[0]
            return out

        return evaluate

    def grid(self, key: str, n: int = 11) -> FloatArray:
        """`n` evenly spaced values of condition `key` over the fitted range."""
        if key not in self.keys:
            raise DataFormatError(f"the database has no condition key {key!r}")
        c, h = self.centres[key], self.half_ranges[key]
        return np.linspace(c - h, c + h, grid_points(n))

    def table(self, *, n: int = 11) -> dict[str, list[Any]]:
        """A tidy table: one row per term and grid point, with the band (`n` points per key);
        with speed terms also rows ``"V0"``, their trim-speed reference (m/s)."""
        axes = np.meshgrid(*[self.grid(k, n) for k in self.keys], indexing="ij")
        flat = {k: a.ravel() for k, a in zip(self.keys, axes, strict=True)}
        rows: dict[str, list[Any]] = {"term": [], **{k: [] for k in self.keys}}
        rows.update(value=[], stderr=[], lower=[], upper=[])
        for term in self.terms:
            # (a key no flight varied spans its value ± 1: the grid's only extrapolation)
            value, se = self._predict(term, flat, warn=False)
            z = self.quantile(term)
            lo, hi = value - z * se, value + z * se
            rows["term"].extend([term] * value.size)
            for k in self.keys:
                rows[k].extend(flat[k].tolist())
            rows["value"].extend(value.tolist())
            rows["stderr"].extend(se.tolist())
            rows["lower"].extend(lo.tolist())
            rows["upper"].extend(hi.tolist())
        if self.speed_reference is not None:
            # the speed terms' reference, with the normal quantile's band
            v0, se = self.trim_speed(flat)
            z = norm_ppf(0.5 + 0.5 * self.confidence)
            rows["term"].extend(["V0"] * v0.size)
            for k in self.keys:
                rows[k].extend(flat[k].tolist())
            rows["value"].extend(v0.tolist())
            rows["stderr"].extend(se.tolist())
            rows["lower"].extend((v0 - z * se).tolist())
            rows["upper"].extend((v0 + z * se).tolist())
        return rows

    def to_jsbsim(self, path: str | Path | None = None, *, n: int = 21) -> str:
        """The database as a JSBSim ``<aerodynamics>`` section (written to `path` if given).

        Tables in JSBSim's variables (``aero/alpha-rad``, ``velocities/mach``,
        ``position/h-sl-ft``, ...) with `n` breakpoints per key over the fitted
        range; terms named ``<C>_<regressor>`` (``Cm_q``, ``Cl_delta_a``; see
        `aeroid.uncertainty.database_export`). JSBSim holds a table's end values outside it.
        """
        from .database_export import jsbsim_aerodynamics, write_jsbsim

        if path is not None:
            write_jsbsim(self, path, n=n)
        return jsbsim_aerodynamics(self, n=n)

    def to_parquet(self, path: str | Path, *, n: int = 11) -> Path:
        """Write `table` (one row per term and grid point, with the band) as Parquet."""
        from .database_export import write_parquet

        return write_parquet(self, path, n=n)

    def summary(self) -> str:
        """A Markdown table of the terms, their structures and fit statistics."""
        rows = []
        for t in self.terms:
            rows.append(
                [
                    t,
                    " + ".join(self.structures[t]),
                    fmt(self.chi2[t]),
                    fmt(self.dof[t], 3),
                    fmt(self.scale[t]),
                    fmt(math.sqrt(self.tau2.get(t, 0.0))),
                ]
            )
        head = (
            f"Aerodynamic database: {len(self.terms)} coefficients over {len(self.flights)} flights, "
            f"condition keys {key_list(self.keys)}\n\n"
        )
        out = head + markdown_table(["term", "structure", "χ²", "dof", "scale", "τ"], rows)
        if self.held_out:
            inside = sum(c.inside for c in self.held_out)
            out += (
                f"\n\nHeld out: {len({c.flight for c in self.held_out})} flights, {inside} of "
                f"{len(self.held_out)} estimates inside the {self.confidence:.0%} band"
            )
        ref = self.speed_reference
        if ref is not None:
            out += (
                f"\n\nSpeed terms ({', '.join(self.speed_terms)}) fly as C_V (V/V0 − 1), V0 the "
                f"trim speed over {key_list(self.keys)}: (V̄/V0)² with V̄ {fmt(ref.scale)} m/s "
                f"= {' + '.join(ref.structure)}, {fmt(ref.rms)} m/s rms about the flights' "
                "trim speeds"
            )
        return out


def _flight_data(
    flights: Sequence[FlightCoefficients], terms: Sequence[str], keys: Sequence[str]
) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
    """Conditions, estimates (NaN where absent) and each flight's covariance over `terms`."""
    x = np.empty((len(flights), len(keys)))
    z = np.full((len(flights), len(terms)), np.nan)
    covs = []
    for i, f in enumerate(flights):
        for j, k in enumerate(keys):
            if k not in f.condition:
                raise DataFormatError(
                    f"flight {f.name!r} has no condition {k!r} (it gives "
                    f"{', '.join(f.condition) or 'no condition at all'})"
                )
            value = float(f.condition[k])
            if not math.isfinite(value):
                raise DataFormatError(f"flight {f.name!r}: condition {k!r} is {value}")
            x[i, j] = value
        names = list(f.estimates)
        cov_f = np.asarray(f.covariance, dtype=np.float64)
        if cov_f.shape != (len(names), len(names)):
            raise DataFormatError(
                f"flight {f.name!r}: covariance is {cov_f.shape}, its {len(names)} estimates "
                f"need ({len(names)}, {len(names)})"
            )
        idx = [names.index(t) if t in names else -1 for t in terms]
        sub = np.full((len(terms), len(terms)), np.nan)
        for a, ia in enumerate(idx):
            if ia < 0:
                continue
            value = float(f.estimates[terms[a]])
            var = cov_f[ia, ia]
            if math.isfinite(value) and math.isfinite(var) and var > 0.0:
                z[i, a] = value
            for b, ib in enumerate(idx):
                if ib >= 0:
                    sub[a, b] = cov_f[ia, ib]
        covs.append(sub)
    return x, z, covs


def aerodynamic_database(
    flights: Sequence[FlightCoefficients],
    *,
    terms: Sequence[str] | None = None,
    keys: Sequence[str] | None = None,
    max_degree: int = 3,
    f_in: float = 4.0,
    structures: Mapping[str, Sequence[str]] | None = None,
    held_out: Sequence[str] = (),
    confidence: float = 0.95,
) -> AeroDatabase:
    """Fit each coefficient as a smooth function of the flight condition over all flights.

    Parameters
    ----------
    flights : sequence of FlightCoefficients
        Per-flight estimates with their covariances and conditions.
    terms : sequence of str, optional
        Coefficients to model (default: every name any flight estimates).
    keys : sequence of str, optional
        Condition keys of the model (default: those every flight gives, in the
        first flight's order); none makes each term a constant.
    max_degree : int
        Highest total degree of the candidate Legendre products.
    f_in : float
        Partial F a candidate needs to enter (module notes).
    structures : mapping of str to sequence of str, optional
        Forced basis per coefficient: ``["1", "alpha", "alpha^2", "alpha*mach"]``
        (powers mean Legendre degrees of the scaled key).
    held_out : sequence of str
        Flights kept out of the fit and checked against it.
    confidence : float
        Level of the bands and of the held-out check.

    Returns
    -------
    AeroDatabase

    Raises
    ------
    DataFormatError
        A flight lacks a condition key, its covariance does not match, or it
        estimates a speed term (``Cm_V``) but gives no trim speed.
    IdentificationError
        No term to fit, no flight excites a term, or the conditions cannot
        identify a forced structure (named).

    Warns
    -----
    UserWarning
        A condition key some flights lack, left out of the default `keys` (named,
        with those flights).
    """
    flights, confidence, max_degree, f_in = database_options(
        flights, FlightCoefficients, confidence, max_degree, f_in
    )
    names = [f.name for f in flights]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise DataFormatError(f"flight name(s) {', '.join(dup)} appear more than once")
    unknown = [h for h in held_out if h not in names]
    if unknown:
        raise DataFormatError(f"held-out flight(s) {', '.join(unknown)} are not among the flights")
    fit = [f for f in flights if f.name not in set(held_out)]
    if not fit:
        raise IdentificationError("no flight is left to fit once the held-out flights are removed")
    for f in fit:
        if not f.condition:
            raise DataFormatError(f"flight {f.name!r} has no condition")
    keys, terms = keys_and_terms(fit, keys, terms)
    x, z, covs = _flight_data(fit, terms, keys)
    lo, hi = x.min(axis=0), x.max(axis=0)
    centres = {k: float(0.5 * (lo[i] + hi[i])) for i, k in enumerate(keys)}
    half = {k: float(0.5 * (hi[i] - lo[i])) or 1.0 for i, k in enumerate(keys)}
    u = scaled(x, keys, centres, half)
    forced = dict(structures or {})
    bad = [t for t in forced if t not in terms]
    if bad:
        raise IdentificationError(
            f"structures name term(s) {', '.join(bad)} that no flight estimates"
        )

    fits: dict[str, TermFit] = {}
    for j, t in enumerate(terms):
        has = np.isfinite(z[:, j])
        if not has.any():
            raise IdentificationError(
                f"no flight excites {t!r}: every flight's estimate is missing or has no finite variance"
            )
        var = np.array([covs[i][j, j] for i in np.flatnonzero(has)])
        uj = u[has]
        if t in forced:
            es = [parse_label(lab, keys, t) for lab in forced[t]]
            check_identifiable(t, es, uj, [fit[i].name for i in np.flatnonzero(has)], keys)
            fits[t] = fit_term(uj, z[has, j], var, forced=es)
        else:
            varying = [bool(np.ptp(uj[:, i]) > 1e-9) for i in range(len(keys))]
            cands = candidate_exponents(len(keys), max_degree, varying)
            fits[t] = fit_term(uj, z[has, j], var, candidates=cands, f_in=f_in)

    reference = fit_trim_speed(fit, terms, z, u, keys, max_degree, f_in)
    offsets, j0 = {}, 0
    for t in terms:
        offsets[t] = j0
        j0 += len(fits[t].exponents)
    stderr = np.sqrt(np.array([np.diag(c) for c in covs]))
    stderr = np.where(np.isfinite(z), stderr, np.nan)
    db = AeroDatabase(
        terms=terms,
        keys=keys,
        centres=centres,
        half_ranges=half,
        structures={t: tuple(label(e, keys) for e in fits[t].selected) for t in terms},
        parameters={t: fits[t].theta for t in terms},
        covariance=_joint_covariance(z, covs, terms, fits),
        scale={t: fits[t].scale for t in terms},
        chi2={t: fits[t].chi2 for t in terms},
        dof={t: fits[t].dof for t in terms},
        flights=tuple(f.name for f in fit),
        conditions=x,
        estimates=z,
        stderr=stderr,
        confidence=confidence,
        tau2={t: fits[t].tau2 for t in terms},
        basis={t: tuple(label(e, keys) for e in fits[t].exponents) for t in terms},
        speed_reference=reference,
        _exponents={t: fits[t].exponents for t in terms},
        _offsets=offsets,
    )
    held = [f for f in flights if f.name in set(held_out)]
    if not held:
        return db
    checks = []
    hx, hz, hcovs = _flight_data(held, terms, keys)
    for i, f in enumerate(held):
        for j, t in enumerate(terms):
            if not np.isfinite(hz[i, j]):
                continue
            pred, se = db._predict(t, hx[i : i + 1], warn=False)  # (outside: its z tells)
            s_est = math.sqrt(hcovs[i][j, j])
            spread = math.sqrt(s_est**2 + db.tau2[t] + se[0] ** 2)
            zval = (hz[i, j] - pred[0]) / spread
            checks.append(
                HeldOutCheck(
                    f.name,
                    t,
                    float(hz[i, j]),
                    s_est,
                    float(pred[0]),
                    float(se[0]),
                    zval,
                    db.quantile(t),
                )
            )
    object.__setattr__(db, "held_out", tuple(checks))
    return db


def _joint_covariance(
    z: FloatArray, covs: Sequence[FloatArray], terms: Sequence[str], fits: Mapping[str, TermFit]
) -> FloatArray:
    """The covariance of every term's basis coefficients: across terms the sandwich
    ``Σ_f g_jf V_f,jk g_kf'`` through each flight's full covariance; each term's own
    block its model-averaged covariance (`fit_term`), which holds that term's part of
    the sandwich and more, so the whole stays positive semi-definite."""
    sizes = [len(fits[t].exponents) for t in terms]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    gains = []
    for jt, t in enumerate(terms):
        g = np.zeros((sizes[jt], z.shape[0]))
        g[:, np.isfinite(z[:, jt])] = fits[t].gain
        gains.append(g)
    owner = np.repeat(np.arange(len(terms)), sizes)
    out = np.zeros((offs[-1], offs[-1]))
    for i, cov in enumerate(covs):
        present = np.isfinite(z[i])
        c = np.where(np.outer(present, present), np.nan_to_num(cov), 0.0)
        g_i = np.concatenate([g[:, i] for g in gains])
        out += np.outer(g_i, g_i) * c[np.ix_(owner, owner)]
    for jt, t in enumerate(terms):
        sl = slice(offs[jt], offs[jt + 1])
        out[sl, sl] = fits[t].covariance
    return 0.5 * (out + out.T)
