"""The simulated-flights source: a deterministic campaign flown by the truth model.

Flight ``i`` of a ``short_period_campaign`` is flown at airspeed ``V_i``
spread evenly over the configured range. The short-period derivatives scale
with flight condition as in the usual quasi-steady model: ``Z_alpha`` and
``M_q`` with airspeed, ``M_alpha`` and ``M_delta`` with dynamic pressure
(reference: the library's truth values at 90 m/s). Each flight's noise
stream is ``SeedSequence(seed, spawn_key=(i,))``, so flights do not depend
on how many others are generated. The elevator flies a ±0.05 rad doublet
from 1 s (``maneuver: doublet``), or that doublet and then, from 4 s to the
end, a 0.2-3 Hz linear sweep of the same amplitude (``doublet_sweep``), which
gives the frequency-domain checks coherent data across the band.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...io.data import FlightData

__all__ = ["GENERATOR_VERSION", "flight_spec", "fly"]

GENERATOR_VERSION = "1"
_V_REF = 90.0
_RHO = 1.0  # kg/m^3, about 2 km altitude
_SWEEP_START = 4.0  # s: after the doublet (1-3 s) has settled


def _truth(airspeed: float) -> dict[str, float]:
    from ...models.catalog import SHORT_PERIOD_TRUTH

    s = airspeed / _V_REF
    return {
        "Z_alpha": SHORT_PERIOD_TRUTH["Z_alpha"] * s,
        "M_alpha": SHORT_PERIOD_TRUTH["M_alpha"] * s * s,
        "M_q": SHORT_PERIOD_TRUTH["M_q"] * s,
        "M_delta": SHORT_PERIOD_TRUTH["M_delta"] * s * s,
    }


def flight_spec(spec: Mapping[str, Any], index: int) -> dict[str, Any]:
    """Everything that determines flight `index` of a campaign spec (its load key hashes this).

    The flight's airspeed is resolved here, so the spec of one flight does
    not mention how many others there are.
    """
    lo, hi = (float(v) for v in spec.get("airspeed", (60.0, 120.0)))
    n = int(spec["n_flights"])
    v = lo if n == 1 else lo + (hi - lo) * index / (n - 1)
    noise = spec.get("noise")
    out: dict[str, Any] = {
        "generator": str(spec.get("generator", "short_period_campaign")),
        "generator_version": GENERATOR_VERSION,
        "index": int(index),
        "seed": int(spec.get("seed", 0)),
        "airspeed": v,
        "duration": float(spec.get("duration", 10.0)),
        "sample_rate": float(spec.get("sample_rate", 50.0)),
        "noise": None if noise is None else {k: float(x) for k, x in dict(noise).items()},
        "colored": float(spec.get("colored", 0.0)),
    }
    maneuver = str(spec.get("maneuver", "doublet"))
    if maneuver != "doublet":  # named only when not the original doublet: its keys stay
        out["maneuver"] = maneuver
    return out


def fly(flight: Mapping[str, Any]) -> FlightData:
    """Fly one simulated flight from its `flight_spec` (noise seeded per flight index)."""
    from ...models.catalog import doublet, frequency_sweep, short_period_flight

    if flight.get("generator_version") != GENERATOR_VERSION:
        raise ValueError(
            f"simulated flight generator version {flight.get('generator_version')!r} "
            f"is not this aeroid's ({GENERATOR_VERSION})"
        )
    v = float(flight["airspeed"])
    truth = _truth(v)
    ss = np.random.SeedSequence(int(flight["seed"]), spawn_key=(int(flight["index"]),))
    seed = int(ss.generate_state(1, dtype=np.uint64)[0])
    noise = flight.get("noise")
    duration, rate = float(flight["duration"]), float(flight["sample_rate"])
    elevator = None
    maneuver = flight.get("maneuver", "doublet")
    if maneuver == "doublet_sweep":
        t = np.arange(round(duration * rate) + 1) / rate
        elevator = np.where(
            t < _SWEEP_START,
            doublet(t),
            frequency_sweep(t, start=_SWEEP_START, f0=0.2, f1=3.0, amplitude=0.05),
        )
    elif maneuver != "doublet":
        raise ValueError(f"simulated flight manoeuvre {maneuver!r} is not known")
    data = short_period_flight(
        parameters=truth,
        duration=duration,
        sample_rate=rate,
        noise=None if noise is None else dict(noise),
        seed=seed,
        colored=float(flight["colored"]),
        elevator=elevator,
    )
    meta = {
        "source": f"simulated {flight['generator']} #{flight['index']}",
        "airspeed": v,
        "dynamic_pressure": 0.5 * _RHO * v * v,
        "truth": truth,
    }
    return FlightData(data.time, data.channels, data.units, meta)
