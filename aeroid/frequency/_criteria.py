"""Published handling-qualities boundaries and the levels they give.

Every number here is pinned by a test to ``shared/reference/handling-qualities.md``,
which names each source; the sources are cited again next to each table.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, ReadOnlyDict, fmt, frozen_mapping, markdown_table
from ..errors import IdentificationError
from ..io.data import as_float
from ._transfer import transfer_response

FloatArray = NDArray[np.float64]

# MIL-STD-1797A short-period LOES limits for q/F_es ``K (s + 1/T_θ2) e^(-τs) / (s² + 2ζω s + ω²)``,
# as E. A. Morelli's `milstd.m` (NASA Langley, 1998; distributed with SIDPAC and Morelli & Klein,
# Aircraft System Identification, 2nd ed.) states them "using the data in MIL-STD 1797A".
# Index 0, 1, 2: Levels 1, 2, 3.
SHORT_PERIOD_ZETA = ((0.35, 1.30), (0.25, 2.00), (0.15, 10.0))  # open intervals
SHORT_PERIOD_OMEGA = (1.0, 0.6, 0.0)  # rad/s, at least
SHORT_PERIOD_OMEGA_T_THETA2 = (1.85, 1.0, 0.0)  # at least
SHORT_PERIOD_TAU = (0.10, 0.20, 0.25)  # s, at most
# a fitted delay closer to zero than this (s) is zero to rounding, not negative
DELAY_ROUNDING = 1e-9
SHORT_PERIOD_SOURCE = (
    "MIL-STD-1797A short-period limits as stated in SIDPAC's milstd.m (E. A. Morelli, "
    "NASA Langley, 1998)"
)

# Pitch-attitude bandwidth / phase delay, Category A: the Level boundaries as digitised in
# `BandwidthCrit.m` (C. Regan, NASA, 2006, "based on Pat Stoliker's routines"; citing
# MIL-STD-1797A Appendix A 4.2.1.2 Section D and Hoh & Hodgkinson, AGARD-CP-333), whose
# author marks them "TODO: check these values": unverified against the standard's figure.
# (ω_BW rad/s, τ_p s) in the routine's order, each a closed patch.
BANDWIDTH_LEVEL_1 = (
    (11.2, 0.0),
    (8.8, 0.06),
    (8.16, 0.055),
    (7.6, 0.05),
    (7.08, 0.045),
    (6.8, 0.04),
    (6.6, 0.035),
    (6.54, 0.03),
    (6.5, 0.02),
    (6.5, 0.0),
)
BANDWIDTH_LEVEL_2 = (
    (3.4, 0.15),
    (2.6, 0.14),
    (2.08, 0.13),
    (1.76, 0.12),
    (1.40, 0.11),
    (1.16, 0.10),
    (1.0, 0.085),
    (1.0, 0.0),
)
BANDWIDTH_SOURCE = (
    "Category A boundaries digitised from BandwidthCrit.m (C. Regan, NASA, 2006), "
    "marked unchecked by its author"
)

# Maximum unnoticeable added dynamics (Wood & Hodgkinson; MIL-STD-1797A's LOES guidance):
# the envelopes of the mismatch HOS/LOES as `LoesBound.m` (C. Regan, NASA, 2006) evaluates
# them, also marked "TODO: check boundary values" there. (numerator, denominator) in
# descending powers of s (rad/s); gains in dB, phases in degrees, no added delay factors.
MUAD_ENVELOPES = {
    "lower_gain_db": ((0.095, 9.92, 2.15), (1.0, 11.6, 4.95)),
    "upper_gain_db": ((3.16, 31.61, 22.79), (1.0, 27.14, 1.84)),
    "lower_phase_deg": ((475.32, 184100.0, 29460.0), (1.0, 11.66, 0.039)),
    "upper_phase_deg": ((68.89, 1100.12, -275.22), (1.0, 39.94, 9.99)),
}
MUAD_SOURCE = (
    "maximum unnoticeable added dynamics envelopes as evaluated in LoesBound.m "
    "(C. Regan, NASA, 2006), marked unchecked by its author"
)


@dataclass(frozen=True, eq=False)
class HandlingQualitiesLevel(FrozenState):
    """A Level (1 best, 3 worst) from a published criterion, criterion by criterion.

    Attributes
    ----------
    level : int
        The worst of the criteria's levels.
    criteria : mapping of str to int
        Each criterion's level.
    values : mapping of str to float
        The values the criteria were read at.
    beyond_level_3 : tuple of str
        The criteria whose values lie outside even the Level 3 limits (still
        reported as Level 3, as the source does).
    source : str
        Where the boundaries come from.
    """

    level: int
    criteria: Mapping[str, int]
    values: Mapping[str, float]
    beyond_level_3: tuple[str, ...] = ()
    source: str = ""
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "criteria", ReadOnlyDict({str(k): int(v) for k, v in self.criteria.items()})
        )
        object.__setattr__(self, "values", frozen_mapping(dict(self.values)))

    def summary(self) -> str:
        """Markdown table of each criterion's value and level, and the overall level."""
        rows = [(k, fmt(self.values.get(k, math.nan)), str(v)) for k, v in self.criteria.items()]
        beyond = (
            f" (beyond the Level 3 limits on {', '.join(self.beyond_level_3)})"
            if self.beyond_level_3
            else ""
        )
        lines = [
            f"**Level {self.level}**{beyond}",
            "",
            markdown_table(("criterion", "value", "level"), rows),
            "",
            f"Source: {self.source}.",
        ]
        lines += [f"Note: {n}" for n in self.notes]
        return "\n".join(lines)


def _number(value: object, name: str) -> float:
    x = as_float(value)
    if x is None or math.isnan(x):
        raise IdentificationError(f"{name}: expected a number, got {value!r}")
    return x


def short_period_level(
    omega: float, zeta: float, t_theta2: float, tau: float
) -> HandlingQualitiesLevel:
    """MIL-STD-1797A Level of a short-period equivalent system (SIDPAC's ``milstd``).

    Parameters
    ----------
    omega : float
        Short-period natural frequency ω_sp, rad/s.
    zeta : float
        Short-period damping ratio ζ_sp.
    t_theta2 : float
        The numerator time constant T_θ2, s (negative for a right-half-plane zero;
        infinite for no zero).
    tau : float
        Equivalent time delay, s.

    Returns
    -------
    HandlingQualitiesLevel
        Criteria ``zeta`` (Level 1 on 0.35 < ζ < 1.30, Level 2 on 0.25 < ζ < 2.00),
        ``omega`` (ω >= 1.0, >= 0.6 rad/s), ``omega*T_theta2`` (>= 1.85, >= 1.0) and
        ``tau`` (<= 0.10, <= 0.20 s); the Level is the worst of the four, as in
        SIDPAC's ``milstd.m``. Values outside the Level 3 limits (0.15 < ζ < 10,
        ω T_θ2 >= 0, τ <= 0.25 s) are named in ``beyond_level_3``.

    Raises
    ------
    IdentificationError
        A value that is not a number.
    """
    w = _number(omega, "omega")
    z = _number(zeta, "zeta")
    t2 = _number(t_theta2, "t_theta2")
    d = _number(tau, "tau")
    wt = w * t2
    levels: dict[str, int] = {}
    beyond: list[str] = []

    def inside_zeta(i: int) -> bool:
        lo, hi = SHORT_PERIOD_ZETA[i]
        return lo < z < hi

    levels["zeta"] = next((i + 1 for i in range(2) if inside_zeta(i)), 3)
    if not inside_zeta(2):
        beyond.append("zeta")
    levels["omega"] = next((i + 1 for i in range(2) if w >= SHORT_PERIOD_OMEGA[i]), 3)
    if not w >= SHORT_PERIOD_OMEGA[2]:
        beyond.append("omega")
    levels["omega*T_theta2"] = next(
        (i + 1 for i in range(2) if wt >= SHORT_PERIOD_OMEGA_T_THETA2[i]), 3
    )
    if not wt >= SHORT_PERIOD_OMEGA_T_THETA2[2]:
        beyond.append("omega*T_theta2")
    levels["tau"] = _tau_level(d)
    if not d <= SHORT_PERIOD_TAU[2]:
        beyond.append("tau")
    return HandlingQualitiesLevel(
        max(levels.values()),
        levels,
        {"zeta": z, "omega": w, "omega*T_theta2": wt, "tau": d},
        tuple(beyond),
        SHORT_PERIOD_SOURCE,
        _short_period_notes(t2, d),
    )


def _tau_level(tau: float) -> int:
    return next((i + 1 for i in range(2) if tau <= SHORT_PERIOD_TAU[i]), 3)


def _short_period_notes(t_theta2: float, tau: float) -> tuple[str, ...]:
    notes = []
    if t_theta2 < 0:
        notes.append("a right-half-plane numerator zero (T_theta2 < 0)")
    if tau < -DELAY_ROUNDING:
        notes.append("a negative time delay")
    return tuple(notes)


def _unstable_short_period_level(
    t_theta2: float, tau: float, root: float
) -> HandlingQualitiesLevel:
    """Level 3 for a short period whose denominator has a real root `root` >= 0.

    Such a mode has no ω or ζ: it is worse than any damping the Level 3 limit
    (ζ > 0.15) admits, so ζ and ω are graded Level 3 and named beyond its limits, as
    `short_period_level` grades a ζ below 0.15; ω T_θ2 is Level 3 for want of ω.
    """
    t2 = _number(t_theta2, "t_theta2")
    d = _number(tau, "tau")
    levels = {"zeta": 3, "omega": 3, "omega*T_theta2": 3, "tau": _tau_level(d)}
    beyond = ["zeta", "omega"] + ([] if d <= SHORT_PERIOD_TAU[2] else ["tau"])
    note = f"an unstable short period: a real denominator root at s = {root:.4g}, no ω or ζ"
    return HandlingQualitiesLevel(
        3,
        levels,
        {"zeta": math.nan, "omega": math.nan, "omega*T_theta2": math.nan, "tau": d},
        tuple(beyond),
        SHORT_PERIOD_SOURCE,
        (note, *_short_period_notes(t2, d)),
    )


def _boundary(points: tuple[tuple[float, float], ...]) -> tuple[FloatArray, FloatArray]:
    """A patch's upper-left edge as τ_p limit against ω_BW, ascending in ω_BW.

    The patches close along the τ_p = 0 axis and, for Level 1, back to (11.2, 0) at the
    plot's right edge; the criterion's boundary is the rest: the vertices from the
    lowest bandwidth to the highest phase delay.
    """
    pts = np.array(points, dtype=np.float64)
    top = int(np.argmax(pts[:, 1]))
    edge = pts[top:]  # from the highest phase delay down to the lowest bandwidth
    edge = edge[edge[:, 1] > 0]  # the vertex on the τ_p = 0 axis closes the patch
    edge = edge[np.argsort(edge[:, 0], kind="stable")]
    return edge[:, 0], edge[:, 1]


def bandwidth_level(bandwidth: float, phase_delay: float) -> HandlingQualitiesLevel:
    """Category A Level from pitch-attitude bandwidth and phase delay.

    A point is Level 1 when its bandwidth reaches the Level 1 boundary's lowest
    bandwidth (6.5 rad/s) and its phase delay lies on or below the boundary there,
    Level 2 likewise for the Level 2 boundary (1.0 rad/s), else Level 3. Beyond a
    boundary's highest vertex its phase-delay limit stays at that vertex's value (the
    routine closes its patches at the plot's edge), so more bandwidth or less phase
    delay never makes the Level worse. The boundaries are digitised from an
    unverified routine (see `BANDWIDTH_SOURCE`).

    Raises
    ------
    IdentificationError
        A value that is not a number.
    """
    w = _number(bandwidth, "bandwidth")
    tp = _number(phase_delay, "phase_delay")

    def meets(points: tuple[tuple[float, float], ...]) -> bool:
        x, y = _boundary(points)
        if w < x[0]:
            return False
        limit = float(np.interp(w, x, y))  # holds the last vertex's delay beyond it
        return tp <= limit

    level = 1 if meets(BANDWIDTH_LEVEL_1) else 2 if meets(BANDWIDTH_LEVEL_2) else 3
    return HandlingQualitiesLevel(
        level,
        {"bandwidth/phase delay": level},
        {"bandwidth": w, "phase_delay": tp},
        (),
        BANDWIDTH_SOURCE,
    )


def muad_envelopes(omega: FloatArray) -> dict[str, FloatArray]:
    """The MUAD envelopes at ω (rad/s): gains in dB, phases in degrees (`MUAD_SOURCE`)."""
    out: dict[str, FloatArray] = {}
    for name, (num, den) in MUAD_ENVELOPES.items():
        h = transfer_response(num, den, omega)
        if name.endswith("_db"):
            out[name] = np.asarray(20.0 * np.log10(np.abs(h)), dtype=np.float64)
        else:
            out[name] = np.asarray(np.degrees(np.angle(h)), dtype=np.float64)
    return out
