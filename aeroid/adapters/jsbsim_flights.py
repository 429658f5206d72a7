"""Flight tests flown by JSBSim's Cessna 172 (``c172x``), recorded as a flight-test engineer would.

`fly_c172x` trims the aircraft at a flight condition with JSBSim's own
trim, flies aileron and rudder doublets and then a 3-2-1-1 on the elevator
(a simulated pilot holds the wings level, and the pitch attitude except
during the elevator input and its free response), with light seeded
turbulence and seeded sensor noise, and returns
the record in SI units and stability-axis quantities (``V``, ``alpha``,
``beta``, body rates, Euler angles, specific forces at the centre of
gravity, surface positions, thrust). `write_flight` writes it as a CSV flight
file in the usual format; `write_campaign` writes a whole set of conditions.

`effective_derivatives` measures the non-dimensional stability and control
derivatives that JSBSim itself flies at a trim, by small central
perturbations of JSBSim's state and controls (not of any AeroID model), so
that identified derivatives can be checked against the simulator's physics.

`c172x_constants` reads the mass, inertias and reference geometry from the
loaded aircraft and converts them to SI, as `aeroid.models.aircraft.AircraftConstants`.
"""

from __future__ import annotations

import atexit
import csv
import hashlib
import math
import os
import re
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import AdapterError, SimulationError
from ..io.data import FlightData
from . import require

__all__ = [
    "C172X_CHANNELS",
    "FlightCondition",
    "c172x_constants",
    "effective_derivatives",
    "fly_c172x",
    "replay_c172x",
    "write_campaign",
    "write_flight",
]

FloatArray = NDArray[np.float64]

_FT = 0.3048
_LBF = 4.4482216152605
_SLUG = 14.593902937206
_SLUGFT2 = _SLUG * _FT * _FT
_PITCH_GAIN = 1.0  # normalised elevator per rad of pitch attitude
_PITCH_DAMPING = 0.3  # normalised elevator per rad/s of pitch rate
_ROLL_GAIN = 0.5  # normalised aileron per rad of bank
_ROLL_DAMPING = 0.2  # normalised aileron per rad/s of roll rate
_ELEVATOR_START = 10.0  # s, the 3-2-1-1's first edge
_ELEVATOR_UNIT = 0.5  # s, its shortest pulse
# The pilot lets go of the pitch attitude while the elevator input runs and for
# 2.5 s of free response after it (Klein & Morelli: a feedback correction during
# the manoeuvre correlates the elevator with the states and blurs the pitch
# derivatives), then holds it again.
_PITCH_RELEASED = (_ELEVATOR_START, _ELEVATOR_START + 7 * _ELEVATOR_UNIT + 2.5)

# Channel, unit, sensor noise standard deviation (SI): typical of a light-aircraft
# flight-test instrumentation package (vanes, a MEMS IMU, an air-data computer).
C172X_CHANNELS: tuple[tuple[str, str, float], ...] = (
    ("V", "m/s", 0.1),
    ("alpha", "rad", 0.002),
    ("beta", "rad", 0.002),
    ("p", "rad/s", 0.002),
    ("q", "rad/s", 0.002),
    ("r", "rad/s", 0.002),
    ("phi", "rad", 0.002),
    ("theta", "rad", 0.002),
    ("ax", "m/s2", 0.03),
    ("ay", "m/s2", 0.03),
    ("az", "m/s2", 0.03),
    ("delta_e", "rad", 0.0),
    ("delta_a", "rad", 0.0),
    ("delta_r", "rad", 0.0),
    ("thrust", "N", 0.0),
)


@dataclass(frozen=True)
class FlightCondition:
    """A trim condition: true airspeed (m/s) and altitude above sea level (m)."""

    airspeed: float
    altitude: float

    def __post_init__(self) -> None:
        if not (20.0 <= float(self.airspeed) <= 70.0):
            raise AdapterError(
                f"c172x airspeed {self.airspeed!r} m/s: expected 20-70 m/s (its flight envelope)"
            )
        if not (0.0 <= float(self.altitude) <= 4000.0):
            raise AdapterError(f"c172x altitude {self.altitude!r} m: expected 0-4000 m")


def _jsbsim() -> Any:
    return require("jsbsim", "jsbsim")


_AIRCRAFT: dict[str, Any] = {}


def _aircraft(aerodynamics: str | None = None, *, direct: bool = False) -> Any:
    """The adapter's sanitised c172x (no ``<output>`` elements: the stock file declares a
    CSV log beside the package and sockets), kept for the process's life; with
    `aerodynamics`, a copy whose ``<aerodynamics>`` section is that one; `direct`, a
    copy whose surfaces follow their commands at once (`_direct_surfaces`)."""
    key = "" if aerodynamics is None else hashlib.sha256(aerodynamics.encode()).hexdigest()
    key += ":direct" if direct else ""
    if key not in _AIRCRAFT:
        from .jsbsim import JsbsimModel

        root = None if key == "" else _root_with(aerodynamics, direct=direct)
        _AIRCRAFT[key] = JsbsimModel("c172x", outputs={"V": "velocities/vt-fps"}, root=root)
    return _AIRCRAFT[key]


def _direct_surfaces(xml: str) -> str:
    """The flight controls' actuators without their lag, rate limit, hysteresis and bias:
    a replay drives the surfaces to the positions a record holds, dynamics and all."""
    start, end = xml.find("<flight_control"), xml.find("</flight_control>")
    if start < 0 or end < 0:
        raise AdapterError("the c172x definition has no <flight_control> section")
    fcs = re.sub(r"<(lag|rate_limit|hysteresis_width|bias)>[^<]*</\1>", "", xml[start:end])
    return xml[:start] + fcs + xml[end:]


def _root_with(aerodynamics: str | None, *, direct: bool = False) -> Path:
    """A private JSBSim data root holding the c172x with `aerodynamics` in place of its own
    (None: its own) and, `direct`, its surfaces following their commands at once."""
    from ..support import replace_aerodynamics

    src = Path(_jsbsim().get_default_root_dir())
    root = Path(tempfile.mkdtemp(prefix="aeroid-c172x-"))
    atexit.register(shutil.rmtree, root, True)  # kept while the process may fly it
    for sub in ("engine", "systems"):
        shutil.copytree(src / sub, root / sub)
    shutil.copytree(src / "aircraft" / "c172x", root / "aircraft" / "c172x")
    xml = root / "aircraft" / "c172x" / "c172x.xml"
    text = xml.read_text()
    if aerodynamics is not None:
        text = replace_aerodynamics(text, aerodynamics)
    xml.write_text(_direct_surfaces(text) if direct else text)
    return root


def _executive(
    condition: FlightCondition,
    *,
    dt: float = 1 / 120,
    aerodynamics: str | None = None,
    direct: bool = False,
) -> Any:
    """A fresh ``FGFDMExec`` with the c172x trimmed in wings-level flight at `condition`."""
    # The step is set before the aircraft loads: the flight controls' components fix
    # theirs then, and with JSBSim's default 1/120 s a 150 Hz flight moved the ailerons
    # at 1.96 rad/s for the file's 1.57 and lagged the elevator at 77 /s for its 60 /s.
    fdm = _aircraft(aerodynamics, direct=direct).executive(dt)
    fdm.set_dt(dt)
    # JSBSim integrates the body rates and the attitude by forward Euler unless told
    # otherwise: half a step behind the continuous-time motion, which a fit reads as an
    # input delay and a bias in the damping. Adams-Bashforth 2 was not enough either: at
    # the 150 Hz step, a calm 60 m/s flight read Cl_p and Cl_delta_a 0.4 % high together
    # (Cl_p +0.59 %, Cl_delta_a +0.30 % against the table about the cg, from a 150 Hz
    # record), the same flight at 300, 600 and 1200 Hz +0.30, +0.23, +0.22 % and
    # +0.00, -0.07, -0.09 % (second order in the step), and with Adams-Bashforth 3
    # (code 4) for the body rates at 150 Hz +0.24 % and -0.05 %, the converged values.
    # Third order, stable for h |lambda| < 0.54; the rotational modes sit near 0.1.
    fdm["simulation/integrator/rate/rotational"] = 4
    fdm["simulation/integrator/position/rotational"] = 4
    fdm["ic/h-sl-ft"] = condition.altitude / _FT
    fdm["ic/vt-fps"] = condition.airspeed / _FT
    fdm["ic/gamma-deg"] = 0.0
    fdm["ic/psi-true-deg"] = 0.0
    fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    fdm["fcs/mixture-cmd-norm"] = 0.87
    try:
        fdm["simulation/do_simple_trim"] = 1
    except Exception as exc:  # JSBSim raises its own TrimFailureException
        raise SimulationError(
            f"jsbsim: the c172x does not trim at {condition.airspeed:g} m/s, "
            f"{condition.altitude:g} m ({exc})"
        ) from None
    return fdm


def _doublet(t: FloatArray, start: float, width: float, amplitude: float) -> FloatArray:
    return amplitude * (
        ((t >= start) & (t < start + width)).astype(float)
        - ((t >= start + width) & (t < start + 2 * width)).astype(float)
    )


def _three_two_one_one(t: FloatArray, start: float, unit: float, amplitude: float) -> FloatArray:
    signs = (1.0, -1.0, 1.0, -1.0)
    widths = (3.0, 2.0, 1.0, 1.0)
    out = np.zeros_like(t)
    edge = start
    for sign, width in zip(signs, widths, strict=True):
        out[(t >= edge) & (t < edge + width * unit)] = sign * amplitude
        edge += width * unit
    return out


def _inputs(t: FloatArray) -> dict[str, FloatArray]:
    """Normalised stick and pedal commands: an aileron doublet from 1 s, a rudder
    doublet from 5 s, then a 3-2-1-1 on the elevator from 10 s (0.5 s unit). The lateral
    inputs come first, while the airspeed is still the trim's (the elevator's
    excursion leaves the speed off trim for the slow phugoid)."""
    return {
        "fcs/aileron-cmd-norm": _doublet(t, 1.0, 1.0, 0.15),
        "fcs/rudder-cmd-norm": _doublet(t, 5.0, 1.0, 0.25),
        "fcs/elevator-cmd-norm": _three_two_one_one(t, _ELEVATOR_START, _ELEVATOR_UNIT, 0.12),
    }


def _record(fdm: Any) -> list[float]:
    mass = float(fdm["inertia/weight-lbs"]) / 32.174049
    fx = float(fdm["forces/fbx-aero-lbs"]) + float(fdm["forces/fbx-prop-lbs"])
    fy = float(fdm["forces/fby-aero-lbs"]) + float(fdm["forces/fby-prop-lbs"])
    fz = float(fdm["forces/fbz-aero-lbs"]) + float(fdm["forces/fbz-prop-lbs"])
    return [
        float(fdm["velocities/vt-fps"]) * _FT,
        float(fdm["aero/alpha-rad"]),
        float(fdm["aero/beta-rad"]),
        float(fdm["velocities/p-rad_sec"]),
        float(fdm["velocities/q-rad_sec"]),
        float(fdm["velocities/r-rad_sec"]),
        float(fdm["attitude/phi-rad"]),
        float(fdm["attitude/theta-rad"]),
        fx / mass * _FT,
        fy / mass * _FT,
        fz / mass * _FT,
        float(fdm["fcs/elevator-pos-rad"]),
        float(fdm["fcs/effective-aileron-pos"]),
        float(fdm["fcs/rudder-pos-rad"]),
        float(fdm["propulsion/engine/thrust-lbs"]) * _LBF,
    ]


def _gusts(t: FloatArray, airspeed: float, sigma: float, seed: int) -> FloatArray:
    """Lateral and vertical gust velocities (m/s) with first-order (Dryden-like) spectra:
    standard deviation `sigma`, scale length 533 m (MIL-F-8785C above 2000 ft), seeded.
    Our own generator rather than JSBSim's, so that the seed fixes the record."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(2,)))
    out = np.zeros((2, t.size))
    if sigma <= 0.0 or t.size < 2:
        return out
    dt = float(t[1] - t[0])
    a = math.exp(-airspeed * dt / 533.0)
    drive = rng.standard_normal((2, t.size)) * sigma * math.sqrt(1.0 - a * a)
    out[:, 0] = rng.standard_normal(2) * sigma
    for k in range(1, t.size):
        out[:, k] = a * out[:, k - 1] + drive[:, k]
    return out


def _samples(steps: FloatArray, every: int) -> FloatArray:
    """Every channel's mean over each sample interval, the steps ``(k - every, k]`` for
    the sample at step ``k`` (the first sample, the trim, as it is).

    A flight-test data system samples through the same anti-aliasing filter on every
    channel, so that no channel leads another; the interval's mean is that filter. A
    point sample of each ``every``-th step would hold the surfaces' doublet edges, which
    the actuators move in a few steps, only at the samples either side, where a model
    that runs the controls between samples (straight or cubic) puts the edge up to half
    an interval late: the 60 m/s flight flown at 1200 Hz read Cl_p and Cl_delta_a
    +0.72 % and +0.26 % from a 50 Hz point record, +0.24 % and -0.04 % from its means,
    +0.18 % and -0.11 % from a 400 Hz record.
    """
    out = np.empty((1 + (steps.shape[0] - 1) // every, steps.shape[1]))
    out[0] = steps[0]
    out[1:] = steps[1:].reshape(-1, every, steps.shape[1]).mean(axis=1)
    return out


def fly_c172x(
    condition: FlightCondition,
    *,
    duration: float = 20.0,
    sample_rate: float = 50.0,
    turbulence: float = 0.2,
    noise: bool = True,
    seed: int = 0,
    aerodynamics: str | None = None,
) -> FlightData:
    """Fly one flight-test record with JSBSim's c172x.

    Parameters
    ----------
    condition : FlightCondition
        Trim airspeed and altitude.
    duration : float
        Record length, s (at least 18 s: the elevator input ends at 13.5 s and the pilot takes the pitch attitude back at 16 s).
    sample_rate : float
        Recording rate, Hz (10-400); JSBSim steps at a whole multiple of it.
    turbulence : float
        Standard deviation of the lateral and vertical gusts, m/s (0: calm air).
    noise : bool
        Add seeded white sensor noise with the standard deviations of `C172X_CHANNELS`.
    seed : int
        Seeds the gusts and the sensor noise: the same seed flies the same record.
    aerodynamics : str, optional
        A JSBSim ``<aerodynamics>`` section flown in place of the c172x's own (an
        exported `aeroid.AeroDatabase`, `AeroDatabase.to_jsbsim`): the same trim
        condition, stick inputs, pilot, gusts and noise, another aircraft's
        aerodynamics.

    Returns
    -------
    FlightData
        Channels of `C172X_CHANNELS` with their units; metadata holds the
        condition, the trim and the seed.

    Raises
    ------
    AdapterError
        JSBSim missing, a condition outside the envelope, or a sample rate
        outside 10-400 Hz.
    SimulationError
        The trim fails or the flight diverges.

    Notes
    -----
    A sample holds every channel's mean over the JSBSim steps of its sample
    interval (the same anti-aliasing filter on every channel, as a flight-test
    data system samples); each step pairs the states with the forces and the
    surface positions its flight controls set in that step. The body rates
    and the attitude are integrated by Adams-Bashforth 3 (JSBSim's default,
    forward Euler, lags a continuous-time model by half a step, which a fit
    reads as an input delay and a bias in the damping; Adams-Bashforth 2 at
    the 150 Hz step read roll damping and aileron power 0.4 % high together);
    JSBSim's alpha-dot terms still use the previous step's accelerations: a
    property of the simulator's time step, not of the record.
    """
    if duration < 18.0:
        raise AdapterError(f"duration {duration!r} s: the c172x test inputs need at least 18 s")
    if not 10.0 <= float(sample_rate) <= 400.0:
        raise AdapterError(f"sample_rate {sample_rate!r} Hz: expected 10-400 Hz")
    if not (math.isfinite(float(turbulence)) and float(turbulence) >= 0.0):
        raise AdapterError(
            f"turbulence {turbulence!r} m/s: expected a gust standard deviation >= 0 (0: calm air)"
        )
    # JSBSim steps at a whole multiple of the recording rate, at least its usual 120 Hz.
    every = math.ceil(120.0 / float(sample_rate) - 1e-9)
    step = 1.0 / (every * float(sample_rate))
    fdm = _executive(condition, dt=step, aerodynamics=aerodynamics)
    n = round(duration * sample_rate) + 1
    t = np.arange(n) / float(sample_rate)
    fine: FloatArray = np.arange((n - 1) * every + 1, dtype=np.float64) * step
    commands = _inputs(fine)
    gusts = _gusts(fine, float(condition.airspeed), float(turbulence), seed)
    trim = {
        "alpha": float(fdm["aero/alpha-rad"]),
        "theta": float(fdm["attitude/theta-rad"]),
        "delta_e": float(fdm["fcs/elevator-pos-rad"]),
        "throttle": float(fdm["fcs/throttle-cmd-norm"]),
    }
    theta_trim = trim["theta"]
    # The trim's own stick and pedal positions: the inputs and the pilot act about them.
    held = {prop: float(fdm[prop]) for prop in commands}
    steps = np.empty((fine.size, len(C172X_CHANNELS)))
    for k in range(fine.size):
        steps[k] = _record(fdm)
        fdm["fcs/rudder-cmd-norm"] = held["fcs/rudder-cmd-norm"] + float(
            commands["fcs/rudder-cmd-norm"][k]
        )
        fdm["atmosphere/gust-east-fps"] = gusts[0, k] / _FT
        fdm["atmosphere/gust-down-fps"] = gusts[1, k] / _FT
        # The pilot holds the pitch attitude and the wings level around the inputs (the
        # c172x's phugoid is lightly damped and its spiral mode diverges slowly), except
        # in pitch during the elevator input; the recorded surfaces include the corrections.
        pitch_held = not _PITCH_RELEASED[0] <= fine[k] < _PITCH_RELEASED[1]
        fdm["fcs/elevator-cmd-norm"] = (
            held["fcs/elevator-cmd-norm"]
            + float(commands["fcs/elevator-cmd-norm"][k])
            + pitch_held
            * (
                _PITCH_GAIN * (float(fdm["attitude/theta-rad"]) - theta_trim)
                + _PITCH_DAMPING * float(fdm["velocities/q-rad_sec"])
            )
        )
        fdm["fcs/aileron-cmd-norm"] = (
            held["fcs/aileron-cmd-norm"]
            + float(commands["fcs/aileron-cmd-norm"][k])
            - (
                _ROLL_GAIN * float(fdm["attitude/phi-rad"])
                + _ROLL_DAMPING * float(fdm["velocities/p-rad_sec"])
            )
        )
        if k + 1 < fine.size and not fdm.run():
            raise SimulationError(f"jsbsim c172x stopped at t = {fine[k]:.3f} s")
    rows = _samples(steps, every)
    if not np.all(np.isfinite(rows)):
        raise SimulationError("jsbsim c172x: the flight diverged (non-finite values)")
    if noise:
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(1,)))
        sigma = np.array([c[2] for c in C172X_CHANNELS])
        rows = rows + rng.standard_normal(rows.shape) * sigma
    channels = {name: rows[:, i] for i, (name, _, _) in enumerate(C172X_CHANNELS)}
    units = {name: unit for name, unit, _ in C172X_CHANNELS}
    meta = {
        "source": f"jsbsim c172x {condition.airspeed:g} m/s {condition.altitude:g} m",
        "airspeed": float(condition.airspeed),
        "altitude": float(condition.altitude),
        "trim": trim,
        "seed": int(seed),
    }
    return FlightData(t, channels, units, meta)


# surface -> (JSBSim command, degrees of deflection per unit command below and above
# zero: the c172x's aerosurface_scale ranges; the aileron's is the effective one, the
# mean of the left and right surfaces' ranges)
_SURFACES = {
    "delta_e": ("fcs/elevator-cmd-norm", 28.0, 23.0),
    "delta_a": ("fcs/aileron-cmd-norm", 17.5, 17.5),
    "delta_r": ("fcs/rudder-cmd-norm", 16.0, 16.0),
}
_DEG = 0.01745  # the c172x's own degree (its aerosurface_scale gain)


def _command(surface: str, position: FloatArray) -> FloatArray:
    """The normalised command that puts `surface` at `position` (rad) through its scale."""
    _, down, up = _SURFACES[surface]
    return np.where(position > 0.0, position / (up * _DEG), position / (down * _DEG))


def replay_c172x(
    record: FlightData,
    condition: FlightCondition,
    *,
    aerodynamics: str | None = None,
    sample_rate: float | None = None,
) -> FlightData:
    """Fly a record's surface deflections again with the c172x, open loop.

    The c172x (or, with `aerodynamics`, the c172x with that ``<aerodynamics>`` section
    in place of its own: an exported `aeroid.AeroDatabase`) is trimmed at `condition`
    and flown with the record's elevator, aileron and rudder: each surface at the new
    trim's position plus the record's deflection from its first half second (the
    pilot's corrections included, as recorded), in calm air, throttle at the trim,
    without sensor noise. The surfaces follow the record exactly: this copy of the
    c172x drops its actuators' lag, rate limit and hysteresis (the record's positions
    already hold them). What the record's gusts did is not flown again: the c172x's own
    aerodynamics replayed this way show what a replay can reach.

    Parameters
    ----------
    record : FlightData
        A record with ``delta_e``, ``delta_a``, ``delta_r`` (rad) and time.
    condition : FlightCondition
        The record's trim airspeed and altitude.
    aerodynamics : str, optional
        A JSBSim ``<aerodynamics>`` section flown in place of the c172x's own.
    sample_rate : float, optional
        The record's rate, Hz (default from its time).

    Returns
    -------
    FlightData
        The channels of `C172X_CHANNELS` at the record's times.

    Raises
    ------
    AdapterError
        JSBSim missing, or the record lacks a surface channel.
    SimulationError
        The trim fails or the flight diverges.
    """
    missing = [s for s in _SURFACES if s not in record.names]
    if missing:
        raise AdapterError(f"replay: the record has no {', '.join(missing)} channel")
    t = np.asarray(record.time, dtype=np.float64)
    rate = float(sample_rate) if sample_rate else 1.0 / float(np.median(np.diff(t)))
    every = math.ceil(120.0 / rate - 1e-9)
    step = 1.0 / (every * rate)
    fdm = _executive(condition, dt=step, aerodynamics=aerodynamics, direct=True)
    fine = t[0] + np.arange((t.size - 1) * every + 1, dtype=np.float64) * step
    start = t <= t[0] + 0.5
    commands = {}
    for surface, (prop, _, _) in _SURFACES.items():
        trim_pos = (
            float(fdm[prop.replace("cmd-norm", "pos-rad")])
            if surface != "delta_a"
            else (float(fdm["fcs/effective-aileron-pos"]))
        )
        y = np.asarray(record[surface], dtype=np.float64)
        # a command set before a step reaches these direct surfaces in that step, and a
        # sample holds the surfaces set in the step ending at it (`fly_c172x` records,
        # then commands): each step is commanded the record's surface at its end
        target = trim_pos + np.interp(fine + step, t, y - float(np.mean(y[start])))
        commands[prop] = (
            float(fdm[prop]) + _command(surface, target) - _command(surface, np.array(trim_pos))
        )
    rows = np.empty((t.size, len(C172X_CHANNELS)))
    for k in range(fine.size):
        if k % every == 0:
            rows[k // every] = _record(fdm)
        for prop, cmd in commands.items():
            fdm[prop] = float(cmd[k])
        if k + 1 < fine.size and not fdm.run():
            raise SimulationError(f"jsbsim c172x stopped at t = {fine[k]:.3f} s")
    if not np.all(np.isfinite(rows)):
        raise SimulationError("jsbsim c172x: the replay diverged (non-finite values)")
    channels = {name: rows[:, i] for i, (name, _, _) in enumerate(C172X_CHANNELS)}
    units = {name: unit for name, unit, _ in C172X_CHANNELS}
    meta = {"source": "jsbsim c172x replay", "airspeed": float(condition.airspeed)}
    return FlightData(t, channels, units, {**meta, "altitude": float(condition.altitude)})


def write_flight(data: FlightData, path: str | os.PathLike[str]) -> Path:
    """Write a flight as CSV: a ``time`` column then every channel, 9 significant digits."""
    out = Path(path)
    names = list(data.names)
    with out.open("w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(["time", *names])
        columns = [data.time, *(data[n] for n in names)]
        for row in zip(*columns, strict=True):
            writer.writerow([f"{v:.9g}" for v in row])
    return out


def write_campaign(
    folder: str | os.PathLike[str],
    conditions: Sequence[FlightCondition],
    *,
    seed: int = 0,
    **options: Any,
) -> list[Path]:
    """Fly every condition (flight ``i`` seeded by ``SeedSequence(seed, spawn_key=(i,))``)
    and write ``flight_XX.csv`` files into `folder`; returns their paths."""
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, cond in enumerate(conditions):
        ss = np.random.SeedSequence(int(seed), spawn_key=(i,))
        flight_seed = int(ss.generate_state(1)[0])
        data = fly_c172x(cond, seed=flight_seed, **options)
        paths.append(write_flight(data, root / f"flight_{i + 1:02d}.csv"))
    return paths


def c172x_constants(altitude: float, *, airspeed: float = 50.0, engine: bool = False) -> Any:
    """The c172x's mass, inertias, reference geometry and thrust-line offset in SI, with
    JSBSim's (ISA) density at `altitude`, read at the trim at `airspeed` (m/s).

    ``Ixz`` is in `aeroid.models.aircraft.AircraftConstants`' sign convention (the tensor
    ``[[Ixx, 0, -Ixz], ...]``): the negative of JSBSim's ``inertia/ixz-slugs_ft2``, whose
    tensor holds ``+ixz`` off the diagonal (JSBSim's angular accelerations under its own
    moments say so). With `engine`, ``engine_momentum`` is the propeller's angular momentum
    at that trim (`AircraftConstants.engine_momentum`: a model given it takes the other
    axis's rate as an input); without, zero.
    """
    from ..models.aircraft import AircraftConstants

    fdm = _executive(FlightCondition(float(airspeed), float(altitude)))
    return AircraftConstants(
        mass=float(fdm["inertia/mass-slugs"]) * _SLUG,
        Ixx=float(fdm["inertia/ixx-slugs_ft2"]) * _SLUGFT2,
        Iyy=float(fdm["inertia/iyy-slugs_ft2"]) * _SLUGFT2,
        Izz=float(fdm["inertia/izz-slugs_ft2"]) * _SLUGFT2,
        Ixz=-float(fdm["inertia/ixz-slugs_ft2"]) * _SLUGFT2,
        S=float(fdm["metrics/Sw-sqft"]) * _FT**2,
        b=float(fdm["metrics/bw-ft"]) * _FT,
        cbar=float(fdm["metrics/cbarw-ft"]) * _FT,
        rho=float(fdm["atmosphere/rho-slugs_ft3"]) * _SLUG / _FT**3,
        # The propeller's pitching moment per unit thrust at the trim: the thrust line's
        # effective offset below the centre of gravity.
        thrust_offset=float(fdm["moments/m-prop-lbsft"])
        / float(fdm["propulsion/engine/thrust-lbs"])
        * _FT,
        engine_momentum=_engine_momentum(fdm) if engine else 0.0,
    )


def _engine_momentum(fdm: Any) -> float:
    """The propeller's angular momentum along the body x axis at the trim, kg m^2/s: JSBSim's
    own gyroscopic yawing moment per unit pitch rate (``N = h q``), by a central difference."""
    state = {
        "ic/vt-fps": float(fdm["velocities/vt-fps"]),
        "ic/alpha-rad": float(fdm["aero/alpha-rad"]),
        "ic/theta-rad": float(fdm["attitude/theta-rad"]),
    }
    ends = []
    for q in (0.02, -0.02):
        for prop, value in {**state, "ic/beta-rad": 0.0, "ic/phi-rad": 0.0}.items():
            fdm[prop] = value
        for rate in ("p", "r"):
            fdm[f"ic/{rate}-rad_sec"] = 0.0
        fdm["ic/q-rad_sec"] = q
        fdm.run_ic()
        ends.append(float(fdm["moments/n-prop-lbsft"]))
    return (ends[0] - ends[1]) / 0.04 * _LBF * _FT


def _coefficients(fdm: Any) -> dict[str, float]:
    """Non-dimensional coefficients at JSBSim's current state: aerodynamic lift and drag
    in stability axes and side force in body axes; the three moments about the centre
    of gravity in body axes, aerodynamic and propeller together (the moments the
    aircraft's motion, and so an identification, responds to)."""
    qs = float(fdm["aero/qbar-psf"]) * float(fdm["metrics/Sw-sqft"])
    b = float(fdm["metrics/bw-ft"])
    c = float(fdm["metrics/cbarw-ft"])
    return {
        "CL": float(fdm["forces/fwz-aero-lbs"]) / qs,
        "CD": float(fdm["forces/fwx-aero-lbs"]) / qs,
        "CY": float(fdm["forces/fby-aero-lbs"]) / qs,
        "Cl": float(fdm["moments/l-total-lbsft"]) / (qs * b),
        "Cm": float(fdm["moments/m-total-lbsft"]) / (qs * c),
        "Cn": float(fdm["moments/n-total-lbsft"]) / (qs * b),
    }


def effective_derivatives(
    condition: FlightCondition, *, alpha_dot: str = "lumped"
) -> dict[str, float]:
    """The stability and control derivatives JSBSim's c172x flies at a trim.

    Central differences of JSBSim's own aerodynamic forces and moments (about
    the centre of gravity) under small perturbations of its state (α, β, p,
    q, r, re-initialised at the trim airspeed and attitude) and of its control
    surfaces (each actuator moved and settled, then the state reset to the
    trim). Rates are non-dimensional (``q c̄/2V``, ``p b/2V``, ``r b/2V``);
    surfaces in rad. Lift is in stability axes; side force and moments in body
    axes. Each perturbation keeps the α̇ that JSBSim's own state equations
    give it (``α̇ ≈ q`` for a pitch-rate perturbation, ``Z_alpha Δα`` for an
    angle-of-attack one), so the ``α̇`` terms are lumped in as an
    identification without an ``α̇`` term lumps them: ``Cm_q`` is the damping
    sum ``Cm_q + Cm_alpha_dot``.

    With ``alpha_dot="separate"`` the c172x's own α̇ terms (its ``CLadot``
    lift and ``Cmadot`` moment) are taken out of every perturbation and
    returned on their own as ``CL_alpha_dot`` and ``Cm_alpha_dot`` (per unit
    ``α̇ c̄/2V``): the derivatives a model with an ``alpha_dot`` term
    (`aeroid.models.aircraft.longitudinal`) identifies. The α̇ lift's arm about the
    centre of gravity stays in, a part in a thousand of ``Cm_alpha``.

    ``Cl_alpha`` and ``Cn_alpha`` are the roll and yaw the angle of attack
    brings in a wings-level trim: the c172x's centre of gravity lies 4.2 in off its
    plane of symmetry (its file loads an 80 lb point mass on the right wing tip), so
    its lift rolls it (``Cl_alpha`` about the lift slope times the offset in spans), a coupling
    that a lateral model about a fixed trim does not hold.

    Parameters
    ----------
    condition : FlightCondition
    alpha_dot : {"lumped", "separate"}

    Returns
    -------
    dict of str to float
        ``CL_alpha, CD_alpha, Cm_alpha, Cl_alpha, Cn_alpha, CL_q, Cm_q, CL_delta_e,
        Cm_delta_e, CY_beta, Cl_beta, Cn_beta, Cl_p, Cn_p, Cl_r, Cn_r, CY_delta_r, Cl_delta_a,
        Cn_delta_a, Cl_delta_r, Cn_delta_r``, and with ``"separate"`` also
        ``CL_alpha_dot, Cm_alpha_dot``.
    """
    if alpha_dot not in ("lumped", "separate"):
        raise AdapterError(f"alpha_dot: expected 'lumped' or 'separate', got {alpha_dot!r}")
    separate = alpha_dot == "separate"
    fdm = _executive(condition)
    alpha0 = float(fdm["aero/alpha-rad"])
    theta0 = float(fdm["attitude/theta-rad"])
    vt = float(fdm["velocities/vt-fps"])
    b = float(fdm["metrics/bw-ft"])
    c = float(fdm["metrics/cbarw-ft"])

    def at(
        *, alpha: float = alpha0, beta: float = 0.0, p: float = 0.0, q: float = 0.0, r: float = 0.0
    ) -> dict[str, float]:
        for prop, value in (
            ("ic/vt-fps", vt),
            ("ic/alpha-rad", alpha),
            ("ic/beta-rad", beta),
            ("ic/theta-rad", theta0),
            ("ic/phi-rad", 0.0),
            ("ic/p-rad_sec", p),
            ("ic/q-rad_sec", q),
            ("ic/r-rad_sec", r),
        ):
            fdm[prop] = value
        fdm.run_ic()
        out = _coefficients(fdm)
        if separate:
            qs = float(fdm["aero/qbar-psf"]) * float(fdm["metrics/Sw-sqft"])
            lift = float(fdm["aero/coefficient/CLadot"]) / qs
            moment = float(fdm["aero/coefficient/Cmadot"]) / (qs * c)
            out.update(
                CL=out["CL"] - lift,
                Cm=out["Cm"] - moment,
                CL_ad=lift,
                Cm_ad=moment,
                ad=float(fdm["aero/alphadot-rad_sec"]) * c / (2.0 * vt),
            )
        return out

    def slope(plus: dict[str, float], minus: dict[str, float], step: float) -> dict[str, float]:
        return {k: (plus[k] - minus[k]) / (2.0 * step) for k in plus}

    da, dr = 0.01, 0.02  # rad, rad/s: small against the trim, large against round-off
    out: dict[str, float] = {}
    plus, minus = at(alpha=alpha0 + da), at(alpha=alpha0 - da)
    s = slope(plus, minus, da)
    out.update(CL_alpha=s["CL"], CD_alpha=s["CD"], Cm_alpha=s["Cm"])
    out.update(Cl_alpha=s["Cl"], Cn_alpha=s["Cn"])
    if separate:
        # the alpha-dot terms over the alpha-dot the alpha perturbation brings
        change = plus["ad"] - minus["ad"]
        out.update(
            CL_alpha_dot=(plus["CL_ad"] - minus["CL_ad"]) / change,
            Cm_alpha_dot=(plus["Cm_ad"] - minus["Cm_ad"]) / change,
        )
    s = slope(at(q=dr), at(q=-dr), dr * c / (2.0 * vt))
    out.update(CL_q=s["CL"], Cm_q=s["Cm"])
    s = slope(at(beta=da), at(beta=-da), da)
    out.update(CY_beta=s["CY"], Cl_beta=s["Cl"], Cn_beta=s["Cn"])
    s = slope(at(p=dr), at(p=-dr), dr * b / (2.0 * vt))
    out.update(Cl_p=s["Cl"], Cn_p=s["Cn"])
    s = slope(at(r=dr), at(r=-dr), dr * b / (2.0 * vt))
    out.update(Cl_r=s["Cl"], Cn_r=s["Cn"])
    for command, position, names in (
        ("fcs/elevator-cmd-norm", "fcs/elevator-pos-rad", {"CL": "CL_delta_e", "Cm": "Cm_delta_e"}),
        (
            "fcs/aileron-cmd-norm",
            "fcs/effective-aileron-pos",
            {"Cl": "Cl_delta_a", "Cn": "Cn_delta_a"},
        ),
        (
            "fcs/rudder-cmd-norm",
            "fcs/rudder-pos-rad",
            {"CY": "CY_delta_r", "Cl": "Cl_delta_r", "Cn": "Cn_delta_r"},
        ),
    ):
        ends = []
        for sign in (1.0, -1.0):
            # Past the actuators' hysteresis; settled, then the state put back at the trim.
            fdm.resume_integration()
            fdm[command] = 0.2 * sign
            for _ in range(120):
                fdm.run()
            ends.append((at(), float(fdm[position])))
        (plus, up), (minus, down) = ends
        fdm[command] = 0.0
        for key, name in names.items():
            out[name] = (plus[key] - minus[key]) / (up - down)
    return out
