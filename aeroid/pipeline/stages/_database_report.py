"""The database's held-out flights flown again in JSBSim with the exported database.

The database stage's check on its held-out flights compares their estimates
with the database; this one flies them. Each held-out flight's recorded
surface deflections are flown open loop by the simulator the campaign names
(``stages.database.replay``: ``c172x``, JSBSim's Cessna 172,
`aeroid.adapters.jsbsim_flights.replay_c172x`), once with the exported
``aerodynamics.xml`` in place of the aircraft's own and once with its own (what
a replay without the record's gusts can reach), both against the record: R²
per output and an overlay plot per flight, in the database's report section.
The replay runs after the tasks, beside the report, as the database's other
files do: it changes no stored result and no key.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ...errors import AeroidError

if TYPE_CHECKING:
    from ...io.data import FlightData
    from ..plans.planning import Plan, Task
    from ..storage.store import ResultStore

__all__ = ["REPLAY_OUTPUTS", "replay_section"]

# the outputs compared (the five) and, plotted beside them, the attitudes and speed
REPLAY_OUTPUTS = ("alpha", "q", "beta", "p", "r")
_PLOTTED = ("V", "alpha", "theta", "q", "beta", "p", "r", "phi")
_REPLAYERS = ("c172x",)


def r_squared(y: Any, fit: Any) -> float:
    """``1 − Σ(y − ŷ)² / Σ(y − ȳ)²``."""
    import numpy as np

    y, fit = np.asarray(y, dtype=float), np.asarray(fit, dtype=float)
    sst = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - fit) ** 2)) / sst if sst > 0 else float("nan")


def _record(the_plan: Plan, store: ResultStore, task: Task, flight: str) -> FlightData:
    i = task.flights.index(flight)
    key = task.upstream["data"][i]
    return store.load(key, task.upstream_stages["data"])


def _plot(name: str, record: FlightData, flown: Mapping[str, FlightData]) -> bytes:
    import numpy as np

    from ...support import figure, figure_png

    channels = [c for c in _PLOTTED if c in record.names]
    fig, axes = figure(len(channels), height=1.5)
    for ax, ch in zip(axes[:, 0], channels, strict=False):
        # a CSV record may carry no units; the simulator's record does
        unit = record.units.get(ch) or next(iter(flown.values())).units.get(ch, "")
        scale, shown = (np.degrees(1.0), "deg") if unit == "rad" else (1.0, unit)
        scale, shown = (np.degrees(1.0), "deg/s") if unit == "rad/s" else (scale, shown)
        ax.plot(record.time, record[ch] * scale, lw=0.8, color="k", label="record")
        for (label, data), style in zip(flown.items(), ("-", "--"), strict=False):
            ax.plot(data.time, data[ch] * scale, lw=0.9, ls=style, label=label)
        ax.set_ylabel(f"{ch} ({shown})" if shown else ch)
    axes[-1, 0].set_xlabel("time (s)")
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[0, 0].set_title(f"{name}: the record flown again in JSBSim", fontsize="small")
    return bytes(figure_png(fig, dpi=72))


def replay_section(
    the_plan: Plan,
    store: ResultStore,
    task: Task,
    held_out: Sequence[str],
    folder: Path,
) -> tuple[str, dict[str, str]]:
    """The held-out replay as Markdown, and the plots it wrote into `folder` (module notes).

    Returns the section (a note where it cannot fly: no simulator named, jsbsim
    missing, no exported section, a flight without its condition) and ``{label: file}``
    of its plots.
    """
    from ...support import fmt, markdown_table

    head = ["### Held-out flights flown again with the database", ""]
    if not held_out:
        return "", {}
    replay = (task.options or {}).get("replay")
    if replay is None:
        return "\n".join(
            [
                *head,
                "Not flown: `stages.database.replay` names no simulator to fly them "
                f"(known: {', '.join(_REPLAYERS)}).",
                "",
            ]
        ), {}
    section = folder / "aerodynamics.xml"
    try:
        import jsbsim  # noqa: F401
    except ImportError:
        note = "Not flown: jsbsim is not installed (`pip install jsbsim` flies them)."
        return "\n".join([*head, note, ""]), {}
    if not section.is_file():
        note = "Not flown: the database has no JSBSim section (its notes say why)."
        return "\n".join([*head, note, ""]), {}
    from ...adapters.jsbsim_flights import FlightCondition, replay_c172x

    aero = section.read_text(encoding="utf-8")
    own = f"{replay}'s own"
    rows, files, notes = [], {}, []
    for name in held_out:
        try:
            record = _record(the_plan, store, task, name)
            meta = dict(record.metadata or {})
            missing = [k for k in ("airspeed", "altitude") if k not in meta]
            if missing:
                notes.append(f"{name}: not flown, its condition lacks {', '.join(missing)}")
                continue
            cond = FlightCondition(float(meta["airspeed"]), float(meta["altitude"]))
            flown = {
                "database": replay_c172x(record, cond, aerodynamics=aero),
                own: replay_c172x(record, cond),
            }
        except (AeroidError, ValueError, KeyError) as exc:
            notes.append(f"{name}: not flown ({exc})")
            continue
        r2 = {k: {c: r_squared(record[c], d[c]) for c in REPLAY_OUTPUTS} for k, d in flown.items()}
        cells = [f"{fmt(r2['database'][c], 3)} ({fmt(r2[own][c], 3)})" for c in REPLAY_OUTPUTS]
        rows.append([name, *cells])
        png = f"replay_{name}.png"
        (folder / png).write_bytes(_plot(name, record, flown))
        files[f"{name} replay"] = png
    text = [
        *head,
        f"Each held-out flight's recorded surface deflections flown open loop by JSBSim's "
        f"{replay} with the exported `aerodynamics.xml` in place of its own, from the "
        "trim at the flight's condition, in calm air; in brackets the same replay with "
        f"the {replay}'s own aerodynamics (the record's gusts are not flown again: what a "
        "replay can reach). R² of each output against the record:",
        "",
    ]
    if rows:
        text += [markdown_table(["flight", *REPLAY_OUTPUTS], rows), ""]
    text += [f"- {n}" for n in notes] + ([""] if notes else [])
    text += [f"![{label}]({png})" + "\n" for label, png in files.items()]
    return "\n".join(text), files
