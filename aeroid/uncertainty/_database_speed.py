"""Speed terms of the aerodynamic database and the trim speed they refer to.

An aircraft model's speed regressor is ``V/V0 − 1`` about the flight's own trim
speed ``V0`` (``CD_V``, ``CL_V``, ``Cm_V``), a reference that changes from flight
to flight. The database carries it as a smooth function of the condition keys,
``V0(x)``, fitted over the flights' trim speeds (each flight's `trim_speed`, by
default its condition's airspeed), and a speed term flies as
``C_V(x) (V/V0(x) − 1)``. Why the trim curve, and not a constant or the speed
at the start of a simulation: the flights fly along it, so the database's static
coefficient ``C_0(x)`` (each flight's coefficient at its trim,
`aeroid.pipeline.stages.database_stage`) is the coefficient along the trim
curve, and its slope over alpha holds the speed's share,
``C_alpha + C_V V0'(alpha)/V0``. The speed term about ``V0(alpha)`` takes that
share away again: at a fixed speed the database's slope over alpha is the
flights' ``C_alpha``, at a fixed alpha its slope over ``V/V0`` is their ``C_V``,
and on the trim curve the term vanishes, so the static table flies unchanged
where the flights flew. The physics agrees where the speed term is a lumped
alpha-dot term (``Cm_V ≈ −Cm_alphadot c̄ g / V0²``): the flight path turns at
``γ̇ = (L − W)/(m V)``, and at one weight ``(L − W)/W = V²/V0(alpha)² − 1``, whose
first order is ``2 (V/V0 − 1)``: zero on the trim curve, where the trim speed is
the one at which the lift at that alpha holds the weight.

The fitted quantity is ``(V̄/V0)²`` (``V̄`` the flights' mean trim speed): at one
weight ``ρ V0² S CL(alpha) / 2 = W``, so ``1/V0²`` is ``ρ(h) CL(alpha)``, nearly
linear in alpha and in altitude, where ``V0`` itself curves steeply
(``CL^{-1/2}``). It is fitted with the same stepwise Legendre regression and
model average, the trim speeds taken as exact (a relative variance of ``1e-12``
keeps the weights finite), so the between-flight variance holds what the keys
do not (weight, power, flap) and the fit is the ordinary least squares of the
curve. A flight that estimates a speed term without a trim speed is an error
naming it.

On the demo campaign the c172x's lumped alpha-dot term (``Cm_V``) flown this way
brings one held-out flight to what the c172x's own tables reach and takes the
other below what the database reaches without it (README, "The aerodynamic
database across the envelope"): the demo leaves the term out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, frozen_array
from ..errors import DataFormatError, IdentificationError
from ._database_fit import candidate_exponents, design, fit_term, label

if TYPE_CHECKING:
    from .database import FlightCoefficients

__all__ = ["TrimSpeedModel", "fit_trim_speed", "is_speed_term"]

FloatArray = NDArray[np.float64]
Exponents = tuple[int, ...]


def is_speed_term(term: str) -> bool:
    """Whether `term` is a speed term, ``<C>_V`` (its regressor ``V/V0 − 1``)."""
    base, _, regressor = term.partition("_")
    return regressor == "V" and base[:1] == "C"


@dataclass(frozen=True, eq=False)
class TrimSpeedModel(FrozenState):
    """The trim speed ``V0`` over the condition keys, the reference of the speed terms.

    ``(scale / V0)²`` is a Legendre model over the database's scaled keys (module
    notes: the trim's lift balances the weight, so it is nearly linear in alpha).

    Attributes
    ----------
    scale : float
        ``V̄``, the fitted flights' mean trim speed (m/s).
    structure : tuple of str
        The structure stepwise regression selects, as labels.
    parameters : ndarray
        Coefficients of the basis functions (the model average).
    covariance : ndarray
        Their covariance.
    rms : float
        The root mean square of the fitted flights' trim speeds about the model (m/s).
    """

    scale: float
    structure: tuple[str, ...]
    parameters: FloatArray
    covariance: FloatArray
    rms: float
    _exponents: tuple[Exponents, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", frozen_array(self.parameters))
        object.__setattr__(self, "covariance", frozen_array(self.covariance))
        object.__setattr__(self, "structure", tuple(self.structure))
        exps = tuple(tuple(int(n) for n in e) for e in self._exponents)
        object.__setattr__(self, "_exponents", exps)

    def evaluate(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``V0`` and its standard error at scaled conditions `u` (rows)."""
        phi = design(u, self._exponents)
        y = phi @ self.parameters
        if np.any(y <= 0.0):
            raise IdentificationError(
                "the trim-speed model is not positive at the condition asked for "
                "(far outside the flown range)"
            )
        var_y = np.einsum("ij,jk,ik->i", phi, self.covariance, phi)
        v0 = self.scale / np.sqrt(y)
        # d V0 / d y = -V0 / (2 y)
        return v0, 0.5 * v0 / y * np.sqrt(np.maximum(var_y, 0.0))


def fit_trim_speed(
    fit: Sequence[FlightCoefficients],
    terms: Sequence[str],
    z: FloatArray,
    u: FloatArray,
    keys: Sequence[str],
    max_degree: int,
    f_in: float,
) -> TrimSpeedModel | None:
    """The trim speed over the keys, ``(V̄/V0)²`` fitted to the flights' trim speeds
    (module notes), if any term is a speed term; None otherwise."""
    speed = [j for j, t in enumerate(terms) if is_speed_term(t)]
    if not speed:
        return None
    for i, f in enumerate(fit):
        excited = [terms[j] for j in speed if np.isfinite(z[i, j])]
        if excited and f.trim_speed is None:
            raise DataFormatError(
                f"flight {f.name!r} estimates {', '.join(excited)}, a speed term about its "
                "trim speed, but gives none (trim_speed, or an airspeed in its condition)"
            )
    has = np.array([f.trim_speed is not None for f in fit])
    v0 = np.array([float(f.trim_speed) for f in fit if f.trim_speed is not None])
    scale = float(np.mean(v0))
    y = (scale / v0) ** 2
    uh = u[has]
    varying = [bool(np.ptp(uh[:, i]) > 1e-9) for i in range(len(keys))]
    cands = candidate_exponents(len(keys), max_degree, varying)
    # the trim speeds are taken as exact: the floor only keeps the weights finite
    tf = fit_term(uh, y, np.full(y.size, 1e-12), candidates=cands, f_in=f_in)
    resid = scale / np.sqrt(np.maximum(design(uh, tf.exponents) @ tf.theta, 1e-12)) - v0
    return TrimSpeedModel(
        scale=scale,
        structure=tuple(label(e, keys) for e in tf.selected),
        parameters=tf.theta,
        covariance=tf.covariance,
        rms=float(np.sqrt(np.mean(resid**2))),
        _exponents=tf.exponents,
    )
