"""The campaign stage ``database``: the aerodynamic database over every flight, and its files.

The stage reads each flight's identified coefficients with their covariance
(``identification``) and its flight condition (``data``: the config's
``condition:``, merged into the loaded data's metadata) and fits
`aeroid.aerodynamic_database`. It reads only a brief of each flight (a few
numbers), so adding a flight computes that flight's tasks and this one.

After the run, `write_database_files` writes the database beside the campaign
report, in ``<report stem>_database/``: ``aerodynamics.xml`` (a JSBSim
``<aerodynamics>`` section), ``database.parquet`` (the tidy table),
``database.md`` (the report section: the fit, the held-out check and the
files) and one band plot per coefficient. The worker that fits the database makes
the plots and the table (`Stage.files`) and hands them over with its status; the
run's own process makes them only for a database it found stored.
"""

from __future__ import annotations

import contextlib
import functools
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from pydantic import Field

from ...errors import AeroidError, ConfigError, DataFormatError, PipelineError
from ...support import CONDITION_NAMES
from ..running.parallel import forked_map
from . import FIGURE_IMPORTS, Stage, StageContext, register_stage
from ._database_report import replay_section
from .signature_options import library_fields

if TYPE_CHECKING:
    from ...uncertainty.database import AeroDatabase
    from ..plans.planning import Plan
    from ..storage.store import ResultStore

__all__ = ["DatabaseOptions", "database_section", "write_database_files"]

# condition keys the stage takes from a flight's metadata unless `keys` names others
CONDITION_KEYS = CONDITION_NAMES
_COEFFICIENT = re.compile(r"^C[LDYlmn](_|$)")


class DatabaseOptions(
    library_fields(  # type: ignore[misc]  # a generated base
        "aeroid.uncertainty.database:aerodynamic_database",
        *("terms", "keys", "max_degree", "f_in", "structures", "held_out", "confidence"),
        max_degree=Field(None, ge=0, le=6),
        f_in=Field(None, gt=0),
        confidence=Field(None, gt=0, lt=1),
    )
):
    """`aeroid.aerodynamic_database` keywords (``terms``: default every identified
    coefficient named ``C<L,D,Y,l,m,n>_...``; ``keys``: default the flight-condition
    keys the flights give, of alpha, beta, airspeed, altitude, mach, dynamic_pressure)."""

    # the simulator that flies the held-out flights again with the exported database,
    # after the run, for the report (`aeroid.pipeline.stages._database_report`): no result
    # changes with it, so it stays out of the key
    replay: Literal["c172x"] | None = None

    execution_only: ClassVar[frozenset[str]] = frozenset({"replay"})
    engine_only: ClassVar[frozenset[str]] = frozenset({"replay"})


def _brief(role: str, record: Any) -> Any:
    """A flight's coefficients with their covariance, or its numeric condition keys."""
    if role == "identification":
        names = list(getattr(record, "parameter_names", ()))
        return {
            "names": names,
            "parameters": {n: float(record.parameters[n]) for n in names},
            "covariance": [[float(v) for v in row] for row in getattr(record, "covariance", [])],
        }
    if role == "data":
        meta = dict(getattr(record, "metadata", {}) or {})
        return {
            k: float(v)
            for k, v in meta.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool)
        }
    return None


def _run_database(ctx: StageContext) -> Any:
    import numpy as np

    from ...uncertainty.database import FlightCoefficients, aerodynamic_database

    opts = ctx.options
    flights = []
    seen: dict[str, None] = {}  # every identified parameter, for the message
    for i, name in enumerate(ctx.flights):
        ident = ctx.brief("identification", i)
        if ident is None or name in ctx.failures:
            continue  # a failed flight offers nothing; the report names its failure
        cond = ctx.brief("data", i) or {}
        wanted = opts.keys or [k for k in CONDITION_KEYS if k in cond]
        condition = {k: cond[k] for k in wanted if k in cond}
        names = ident["names"]
        seen.update(dict.fromkeys(names))
        keep = [j for j, n in enumerate(names) if opts.terms is None and _COEFFICIENT.match(n)]
        if opts.terms is not None:
            keep = [j for j, n in enumerate(names) if n in opts.terms]
        cov = np.asarray(ident["covariance"], dtype=float)
        if cov.shape != (len(names), len(names)):
            cov = np.full((len(names), len(names)), math.nan)
        sub = cov[np.ix_(keep, keep)] if keep else np.zeros((0, 0))
        est = {names[j]: ident["parameters"][names[j]] for j in keep}
        est, sub = _at_condition(est, sub, cond)
        # the speed terms' V/V0 - 1 refers to the flight's trim speed: its condition's
        # airspeed, whether or not the database is a function of it
        v0 = cond.get("airspeed")
        flights.append(FlightCoefficients(name, condition, est, sub, v0))
    if not flights:
        raise PipelineError("database: no flight was identified; there is nothing to fit")
    if opts.terms is None and not any(f.estimates for f in flights):
        raise ConfigError(_no_coefficient(list(seen)))
    keys = opts.keys
    if keys is not None and not keys:
        # (the library's keyless database is a constant per term; the band plots need a key)
        raise ConfigError("database: stages.database.keys is empty; name a condition key")
    if keys is None:
        present = {k for f in flights for k in f.condition}
        keys = [k for k in CONDITION_KEYS if k in present]
        if not keys:
            raise PipelineError(
                f"database: no flight gives a condition ({', '.join(CONDITION_KEYS)}); "
                f"give each flight one in the config, or name the keys in stages.database.keys"
            )
    kw = opts.library_kwargs(exclude=("keys", "held_out", "replay"))
    return aerodynamic_database(flights, keys=keys, held_out=tuple(opts.held_out or ()), **kw)


def _no_coefficient(names: list[str]) -> str:
    """Why the default terms select nothing: the flights' parameters, none named as a
    coefficient (a model of dimensional derivatives, short_period's ``M_alpha``)."""
    listed = ", ".join(names[:12]) + (f", ... {len(names) - 12} more" if len(names) > 12 else "")
    return (
        "database: no identified parameter is a coefficient named C<L,D,Y,l,m,n>_... "
        f"(the flights identify {listed or 'no parameter'}); name the terms to "
        "tabulate in stages.database.terms"
    )


def _at_condition(
    est: dict[str, float], cov: Any, cond: Mapping[str, float]
) -> tuple[dict[str, float], Any]:
    """Each static ``<C>_0`` moved to the flight's own angles: ``C_0 + C_alpha alpha +
    C_beta beta`` with the condition's alpha and beta (rad), its covariance with them.

    An aircraft model's expansion is about zero angle (``C = C_0 + C_alpha alpha +
    ...``, alpha absolute), so its ``C_0`` is the coefficient extrapolated to alpha =
    0; the database tabulates the coefficient where each flight flew (what the JSBSim
    export reads as the static coefficient over alpha, ``C_alpha`` its slope).
    """
    import numpy as np

    names = list(est)
    jac = np.eye(len(names))
    for j, n in enumerate(names):
        if not n.endswith("_0"):
            continue
        for key in ("alpha", "beta"):
            slope = f"{n[:-2]}_{key}"
            if slope in est and key in cond:
                jac[j, names.index(slope)] = float(cond[key])
    if np.array_equal(jac, np.eye(len(names))):
        return est, cov
    z = jac @ np.array([est[n] for n in names])
    return dict(zip(names, (float(v) for v in z), strict=True)), jac @ cov @ jac.T


register_stage(
    Stage(
        "database",
        # 2: each coefficient weighted by its own variances (aeroid.uncertainty.database notes);
        # 3: each static <C>_0 at the flight's own alpha and beta (_at_condition);
        # 4: random-effects meta-regression, model-averaged Knapp-Hartung bands;
        # 5: speed terms with their trim-speed reference over the keys; 6: a product
        # enters with the factors it lacks
        "6",
        DatabaseOptions,
        "AeroDatabase",
        _run_database,
        uses_model=False,
        per_flight=False,
        brief=_brief,
        # its plots are drawn by the worker that fits it (`_made_files`)
        imports=FIGURE_IMPORTS,
        files=lambda db: _made_files(db),
    )
)


# -- the report section and the files ---------------------------------------------------------


def database_section(db: AeroDatabase, files: Mapping[str, str] | None = None) -> str:
    """The database as a Markdown report section: fit, held-out check, band plots, files."""
    from ...support import fmt, markdown_table

    parts = ["## Aerodynamic database", "", db.summary(), ""]
    if db.held_out:
        rows = [
            [
                c.flight,
                c.term,
                fmt(c.estimate),
                fmt(c.stderr),
                fmt(c.prediction),
                fmt(c.z, 3),
                "yes" if c.inside else f"no (|z| > {fmt(c.limit, 3)})",
            ]
            for c in db.held_out
        ]
        parts += [
            "### Held-out flights",
            "",
            markdown_table(
                ["flight", "term", "estimate", "std error", "database", "z", "inside"],
                rows,
            ),
            "",
        ]
    rows = []
    for i, flight in enumerate(db.flights):
        cond = ", ".join(f"{k} {db.conditions[i, j]:.4g}" for j, k in enumerate(db.keys))
        rows.append([flight, cond])
    parts += ["### Flights in the fit", "", markdown_table(["flight", "condition"], rows), ""]
    for name, rel in (files or {}).items():
        if rel.endswith(".png"):
            parts += [f"![{name}]({rel})", ""]
    listed = [
        f"- {name}: `{rel}`" for name, rel in (files or {}).items() if not rel.endswith(".png")
    ]
    if listed:
        parts += ["### Files", "", *listed, ""]
    return "\n".join(parts)


def _plot_name(term: str) -> str:
    return f"{term}.png"


_TABLE = "database.parquet"


def _made_files(db: AeroDatabase) -> dict[str, bytes]:
    """Every coefficient's band plot (`_band_plot`) and the Parquet table (where pyarrow
    is installed) by file name: made by the worker that fitted the database, beside the
    report's last figures, instead of by the run's own process once every task is
    done (`Stage.files`)."""
    import tempfile

    out = {_plot_name(term): _band_plot(db, term) for term in db.terms}
    with contextlib.suppress(ImportError), tempfile.TemporaryDirectory() as tmp:
        out[_TABLE] = db.to_parquet(Path(tmp) / _TABLE).read_bytes()
    return out


def _band_plot(db: AeroDatabase, term: str) -> bytes:
    """One coefficient's estimates (each flight labelled) and the 95 % band against the first key."""
    from ...reports.plotting import figure, recycle_figure, reusing_figures

    key = db.keys[0]
    j = db.terms.index(term)
    # every term's plot has this layout: the next term drawn in this process redraws
    # the figure instead of building its panel and ticks again (pixel for pixel the same)
    with reusing_figures():
        fig, axes = figure(1, height=3.0, reuse="database_band")
        png = _draw_band(db, term, key, j, fig, axes[0, 0])
        recycle_figure(fig)
    return png


def _draw_band(db: AeroDatabase, term: str, key: str, j: int, fig: Any, ax: Any) -> bytes:
    import numpy as np

    from ...support import figure_png

    x = db.grid(key, 41)
    others = {k: db.centres[k] for k in db.keys if k != key}
    value, lo, hi = db.band(term, {**others, key: x})
    ax.fill_between(x, lo, hi, alpha=0.25, label=f"{db.confidence:.0%} band")
    ax.plot(x, value, lw=1.0, label="database")
    has = np.isfinite(db.estimates[:, j])
    ax.errorbar(
        db.conditions[has, 0],
        db.estimates[has, j],
        yerr=1.96 * db.stderr[has, j],
        fmt="o",
        ms=3,
        capsize=2,
        label="flights",
    )
    # each point names its flight; past 30 flights the names would hide the points
    # (the section's table lists every flight's condition)
    for i in np.flatnonzero(has) if has.sum() <= 30 else ():
        ax.annotate(db.flights[i], (db.conditions[i, 0], db.estimates[i, j]), fontsize=5)
    ax.set_xlabel(key + (" (others at their centre)" if others else ""))
    ax.set_ylabel(term)
    ax.legend(loc="best", fontsize="small")
    return bytes(figure_png(fig, dpi=72))


# The file a run writes last into the database's folder: what the files were written
# from (`_files_stamp`) and each file's size. A rerun that finds it unchanged and every
# file in place writes nothing (the plots cost more than the rest of an unchanged run).
_STAMP = ".aeroid-files"


def _files_stamp(task: Any) -> str:
    """A digest of what the database's files depend on: the stage's result (its key), its
    options (the replay is not in the key), the release, and whether jsbsim can fly
    the replay."""
    import hashlib
    import importlib.util

    from ... import __version__
    from ..keys import canonical_json

    flies = importlib.util.find_spec("jsbsim") is not None
    what = canonical_json([task.key, dict(task.options or {}), __version__, flies])
    return hashlib.sha256(what).hexdigest()


def _written(folder: Path, stamp: str) -> bool:
    """Whether `folder` holds the files written from `stamp`, each of its recorded size."""
    try:
        lines = (folder / _STAMP).read_text(encoding="utf-8").splitlines()
        if not lines or lines[0] != stamp:
            return False
        for line in lines[1:]:
            name, size = line.rsplit(" ", 1)
            if (folder / name).stat().st_size != int(size):
                return False
    except (OSError, ValueError):
        return False
    return len(lines) > 1


def _stamp(folder: Path, stamp: str) -> None:
    sizes = [
        f"{p.name} {p.stat().st_size}"
        for p in sorted(folder.iterdir())
        if p.is_file() and p.name != _STAMP
    ]
    (folder / _STAMP).write_text("\n".join([stamp, *sizes]) + "\n", encoding="utf-8")


def write_database_files(
    the_plan: Plan, store: ResultStore, statuses: Mapping[str, Any]
) -> tuple[Path | None, str | None]:
    """Write the database's files beside the campaign report (module notes).

    Returns (the folder or None, the error that kept the files from being written or None).
    """
    task = next((t for t in the_plan.tasks if t.stage == "database"), None)
    if task is None:
        return None, None
    status = statuses.get(task.key)
    if status is None or status.status == "failed":
        return None, None
    report = the_plan.config.report_path
    folder = report.parent / f"{report.stem}_database"
    stamp = _files_stamp(task)
    if _written(folder, stamp):
        return folder, None  # an unchanged rerun: the files are those of this database
    try:
        db = store.load(task.key, task.stage)
        folder.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            (folder / _STAMP).unlink()  # written again last, once every file is
        files: dict[str, str] = {}
        notes = []
        try:
            db.to_jsbsim(folder / "aerodynamics.xml")
            files["JSBSim aerodynamics section"] = "aerodynamics.xml"
        except DataFormatError as exc:
            # dimensional derivatives (M_q) or a table of three keys: no JSBSim section
            notes.append(f"No JSBSim section: {exc}")
        given: dict[str, bytes] = dict(getattr(status, "files", None) or {})
        try:
            if _TABLE in given:
                (folder / _TABLE).write_bytes(given[_TABLE])
            else:
                db.to_parquet(folder / _TABLE)
            files["tidy table (Parquet)"] = _TABLE
        except ImportError:
            pass  # pyarrow is optional
        plots = [given.get(_plot_name(term), b"") for term in db.terms]
        if not all(plots):
            # a stored database (or plots that failed on the worker): drawn here, in
            # parallel, the run's worker processes being gone and the cores idle
            plots = forked_map(functools.partial(_band_plot, db), db.terms)
        for term, png_bytes in zip(db.terms, plots, strict=True):
            png = folder / _plot_name(term)
            png.write_bytes(png_bytes)
            files[term] = png.name
        held = list(task.options.get("held_out") or [])
        replay, _ = replay_section(the_plan, store, task, held, folder)
        text = database_section(db, files) + "".join(f"\n{n}\n" for n in notes) + replay
        (folder / "database.md").write_text(text, encoding="utf-8")
        _stamp(folder, stamp)
    except (AeroidError, OSError) as exc:
        return None, f"cannot write the aerodynamic database files: {exc}"
    return folder, None


def with_database(text: str, folder: Path) -> tuple[str, dict[str, bytes]]:
    """The report text with the database's section (from its folder's ``database.md``,
    its links made relative to the report) before "What was flown", and its plots."""
    try:
        section = (folder / "database.md").read_text(encoding="utf-8")
    except OSError:
        return text, {}
    rel = folder.name
    section = section.replace("](", f"]({rel}/").replace(": `", f": `{rel}/")
    section += f"\nAll of the database's files are in `{rel}/`, beside this report.\n"
    figures = {}
    for png in sorted(folder.glob("*.png")):
        with contextlib.suppress(OSError):
            figures[f"{rel}/{png.name}"] = png.read_bytes()
    mark = "\n## What was flown"
    at = text.find(mark)
    if at < 0:
        return text.rstrip("\n") + "\n\n" + section, figures
    return text[:at] + "\n" + section.rstrip("\n") + "\n" + text[at:], figures
