"""The database against the c172x's own XML tables (issue 51, part 4, without the records).

Each of 14 trims of JSBSim's c172x (25-65 m/s at 500, 1500 and 2500 m: trim alpha
0-11 deg) gives the derivatives JSBSim flies there (`effective_derivatives`, alpha-dot
terms apart) and the lift coefficient at the trim; seeded noise of 5 % stands in for
one flight's identification. The database over alpha and altitude must meet the
issue's targets at the c172x's table breakpoints inside the flown alpha range.
Two more trims are held out.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jsbsim")

from aeroid.uncertainty.database import FlightCoefficients, aerodynamic_database

# the c172x's tables (c172x.xml): constants, Cn_beta the slope of its beta table,
# CL the CLwbh table at stall hysteresis 0. Cm_alpha is not among them: the slope of
# the moment about the centre of gravity adds lift and drag about the cg and the
# propeller to the table's -1.8 (JSBSim flies -1.5 at 0 deg, -2.5 at 10 deg)
TABLE = {
    "Cm_q": -12.4,
    "Cm_delta_e": -1.28,
    "Cl_p": -0.47,
    "Cl_delta_a": 0.23,
    "Cn_beta": 0.0227 / 0.349,
    "Cn_r": -0.099,
}
CL_TABLE = {
    0.0: 0.25,
    0.09: 0.73,
    0.1: 0.83,
    0.12: 0.92,
    0.14: 1.02,
    0.16: 1.08,
    0.17: 1.13,
    0.19: 1.19,
    0.21: 1.25,
}
SPEEDS = (25.0, 28.0, 32.0, 38.0, 48.0, 58.0)


TRUTH: dict[str, dict[str, float]] = {}  # noise-free values by trim


def _flights() -> list[FlightCoefficients]:
    from aeroid.adapters.jsbsim_flights import (
        FlightCondition,
        _executive,
        effective_derivatives,
    )

    rng = np.random.default_rng(51)
    out = []
    conditions = [(v, h) for h in (500.0, 1500.0, 2500.0) for v in SPEEDS][:14]
    conditions += [(30.0, 1000.0), (45.0, 2000.0)]  # held out
    for i, (v, h) in enumerate(conditions):
        cond = FlightCondition(v, h)
        fdm = _executive(cond)
        alpha = float(fdm["aero/alpha-rad"])
        truth = effective_derivatives(cond, alpha_dot="separate")
        truth = {k: truth[k] for k in (*TABLE, "Cm_alpha")}
        # lift at the trim alpha with the surfaces neutral (the elevator's lift is a term
        # of its own in an identification): JSBSim's fwz force also holds the propeller's
        lift = sum(fdm[f"aero/coefficient/{n}"] for n in ("CLwbh", "CLDf", "CLadot", "CLq"))
        truth["CL_0"] = lift / fdm["aero/qbar-area"]
        sd = {k: 0.05 * abs(x) + 1e-3 for k, x in truth.items()}
        sd["CL_0"] = 0.01 * truth["CL_0"]  # trim lift is weight over q S: well determined
        est = {k: x + sd[k] * rng.standard_normal() for k, x in truth.items()}
        name = f"trim_{i:02d}"
        TRUTH[name] = truth
        out.append(FlightCoefficients.from_stderr(name, {"alpha": alpha, "altitude": h}, est, sd))
    return out


def test_database_meets_the_c172x_tables() -> None:
    flights = _flights()
    db = aerodynamic_database(flights, held_out=("trim_14", "trim_15"))
    lo = db.centres["alpha"] - db.half_ranges["alpha"]
    hi = db.centres["alpha"] + db.half_ranges["alpha"]
    inside = total = 0
    for alt in (500.0, 1500.0, 2500.0):
        for a, cl in CL_TABLE.items():
            if not lo <= a <= hi:
                continue
            value, low, high = db.band("CL_0", {"alpha": a, "altitude": alt})
            assert abs(value[0] - cl) <= max(0.10 * abs(cl), 0.02), (a, alt, value[0], cl)
            inside += int(low[0] <= cl <= high[0])
            total += 1
        grid = db.grid("alpha", 7)
        for term, t in TABLE.items():
            value, low, high = db.band(term, {"alpha": grid, "altitude": alt})
            assert np.all(np.abs(value - t) <= np.maximum(0.10 * abs(t), 0.02)), (term, value, t)
            inside += int(np.sum((low <= t) & (t <= high)))
            total += grid.size
    # 0.94 here (0.76 with release 0.5.0's fixed-effect fit): the estimates follow the
    # derivatives JSBSim flies, which differ from its tables by a few per cent (Cm_delta_e
    # and Cl_p change with alpha) and scatter about them by that much more than their
    # stated errors; the random-effects band carries the scatter (the 0.90)
    assert inside / total >= 0.90, inside / total
    # against what the aircraft flies, at every trim in the fit: Cm_alpha bends with
    # alpha, and at the highest trim (13 deg) 5 % noise on 14 flights left its curvature
    # out of the selected structure (10.3 % off there)
    inside = total = close = 0
    for i, name in enumerate(db.flights):
        cond = {"alpha": db.conditions[i, 0], "altitude": db.conditions[i, 1]}
        for term in db.terms:
            t = TRUTH[name][term]
            value, low, high = db.band(term, cond)
            close += int(abs(value[0] - t) <= max(0.10 * abs(t), 0.02))
            inside += int(low[0] <= t <= high[0])
            total += 1
    assert close / total >= 0.97, close / total
    assert inside / total >= 0.90, inside / total  # 0.94
    assert sum(c.inside for c in db.held_out) >= len(db.held_out) - 1  # 15 of 16
