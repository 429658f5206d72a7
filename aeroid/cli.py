"""The ``aeroid`` command: run, inspect and check campaign pipelines.

Imports stay lazy so that an unchanged rerun costs only key computation and
cache checks: Dask is imported only when something has to be computed.
"""

from __future__ import annotations

import json
import sys
from typing import Any

import click

from ._version import __version__

__all__ = ["main"]


def _fail(message: str, code: int = 2) -> None:
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def _open_store(config: str | None, store: str | None, *, repair: bool = False) -> Any:
    from .errors import AeroidError
    from .pipeline.plans.config import load_config
    from .pipeline.storage.store import ResultStore

    if config and store:
        _fail("give --config or --store, not both")
    try:
        if store:
            return ResultStore(store, create=False, repair=repair)
        if config:
            from .pipeline.definition import resolve_pipeline

            cfg = load_config(config)
            # registers the pipeline's record types
            allowed = bool(getattr(cfg, "allow_imports", False))
            resolve_pipeline(cfg.pipeline, cfg.base_dir, allow_imports=allowed)
            return ResultStore(cfg.store_location, create=False, repair=repair)
    except AeroidError as exc:
        _fail(str(exc))
    _fail("give the store: --config CONFIG or --store PATH")
    raise AssertionError  # unreachable


_MAX_WARNINGS = 10


def _table(header: list[str], rows: list[list[str]]) -> str:
    from ._records import markdown_table

    return markdown_table(header, rows)


# `aeroid status` lists every task up to this many, else a summary per step and the
# first missing tasks
_STATUS_ROWS = 500
_MISSING_SHOWN = 20
# the terminal's results table: at most this many characters a row (the report has it all)
_TABLE_WIDTH = 100
# the campaign table's columns the terminal shows; the estimates are in the report
_SHOWN = ("flight", "condition", "fit", "status")


def _worst_fit(cell: str) -> str:
    """'V 77.6 %, alpha 70.4 %' -> 'alpha 70.4 %' (the worst output's fit)."""
    parts = [p.strip().rsplit(" ", 2) for p in cell.split(",")]
    scored = []
    for p in parts:
        try:
            scored.append((float(p[-2]), " ".join(p)))
        except (ValueError, IndexError):
            return cell
    return f"worst {min(scored)[1]}" if scored else cell


def _metric(header: list[str], rows: list[list[str]]) -> str | None:
    """The propagated metric's name and unit, where some flight has a value of it."""
    for j, h in enumerate(header):
        if "(mean ± " in h and any(str(r[j]) != "—" for r in rows):
            return h.split(" (mean ± ")[0]
    return None


def _narrow_table(header: list[str], rows: list[list[str]]) -> tuple[str, int]:
    """The results table cut to `_TABLE_WIDTH` characters a row: the campaign's summary
    columns (the estimates stay in the report), cells shortened with an ellipsis.
    Returns (table, number of columns left out)."""
    # the propagated metric's column is named after it: "<metric> [unit] (mean ± 1σ)"
    keep = [j for j, h in enumerate(header) if h in _SHOWN or "(mean ± " in h]
    if len(keep) < 2 or len(_table(header, rows).split("\n", 1)[0]) <= _TABLE_WIDTH:
        keep = list(range(len(header)))
    elif _metric(header, rows) is None:  # no step propagated a metric: no empty column
        keep = [j for j in keep if "(mean ± " not in header[j]]
    # the metric's name and unit are enough here; its mean ± 1σ the footnote says
    head = [header[j].split(" (mean ± ")[0] for j in keep]
    body = [[str(r[j]) for j in keep] for r in rows]
    if "fit" in head:
        k = head.index("fit")
        for r in body:
            r[k] = _worst_fit(r[k])
    # a header's unit ("name [unit]") may go where the cells are narrower than it
    widths = [max([len(h.split(" [")[0]), *(len(r[j]) for r in body)]) for j, h in enumerate(head)]
    if body and "condition" in head and sum(widths) + 3 * len(head) + 1 > _TABLE_WIDTH:
        # the condition (the report has it) gives way to the status, which ranks the flights
        k = head.index("condition")
        keep, head, widths = (
            keep[:k] + keep[k + 1 :],
            head[:k] + head[k + 1 :],
            widths[:k] + widths[k + 1 :],
        )
        body = [r[:k] + r[k + 1 :] for r in body]
    cols = len(head)
    widths = widths if body else []
    # shorten the widest column until the row fits (a cell keeps at least 8 characters);
    # the status, which ranks the flights, counts at half its width
    weight = [0.5 if h == "status" else 1.0 for h in head]
    while widths and sum(widths) + 3 * cols + 1 > _TABLE_WIDTH:
        j = max(range(cols), key=lambda i: (widths[i] > 8, widths[i] * weight[i]))
        if widths[j] <= 8:
            break
        widths[j] -= 1
    cut = [
        [c if len(c) <= widths[j] else c[: widths[j] - 1] + "…" for j, c in enumerate(r)]
        for r in body
    ]
    head = [h if len(h) <= widths[j] else h.split(" [")[0] for j, h in enumerate(head)]
    head = [h if len(h) <= widths[j] else h[: widths[j] - 1] + "…" for j, h in enumerate(head)]
    return _table(head, cut), len(header) - len(keep)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(version=__version__, prog_name="aeroid")
def main() -> None:
    """AeroID campaign pipeline: content-keyed stages in a Zarr store, run by Dask."""


@main.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option(
    "--store", type=click.Path(file_okay=False), help="Result store (overrides the config)."
)
@click.option("--scheduler", metavar="ADDRESS", help="tcp://HOST:PORT of a dask scheduler.")
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    help="Worker processes of the embedded cluster (0: run in this process).",
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document on stdout.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar and no tables.")
@click.option(
    "--allow-imports",
    is_flag=True,
    help="Allow 'module:attribute' models and metrics (they import and run that code).",
)
def run(
    config: str,
    store: str | None,
    scheduler: str | None,
    workers: int | None,
    as_json: bool,
    quiet: bool,
    allow_imports: bool,
) -> None:
    """Compute every missing result of the campaign in CONFIG and write its report."""
    from .errors import AeroidError
    from .pipeline.running.runner import run as run_campaign

    try:
        summary = run_campaign(
            config,
            store=store,
            scheduler=scheduler,
            workers=workers,
            progress=not quiet and not as_json,
            allow_imports=allow_imports,
        )
    except AeroidError as exc:
        _fail(str(exc))
        return
    except KeyboardInterrupt:
        # every result committed before the interrupt is kept, intact; nothing half-written
        # is visible (partial writes stay under .tmp for `aeroid gc`)
        click.echo(
            "interrupted: the results stored so far are kept; run the same command again "
            "to compute only what is missing",
            err=True,
        )
        sys.exit(130)
    doc = summary.to_json()
    if as_json:
        click.echo(json.dumps(doc, indent=2))
    # with --json, stdout holds the document alone: the warnings go to stderr; else
    # they come before the table, each naming its flight
    caught = summary.warnings()
    for task, text in caught[:_MAX_WARNINGS]:
        where = f"{task.step} {task.flight}" if task.flight else task.step
        # a cached result's warnings were stored with it when it was computed
        how = ", cached" if summary.statuses[task.key].status == "cached" else ""
        click.echo(f"WARNING {where} ({task.key[:12]}{how}): {text}", err=as_json)
    if len(caught) > _MAX_WARNINGS:
        click.echo(
            f"... {len(caught) - _MAX_WARNINGS} more warnings "
            "(`aeroid show KEY` lists a result's warnings)",
            err=as_json,
        )
    if not as_json and not quiet and summary.rows:
        table, left_out = _narrow_table(summary.columns, summary.rows)
        click.echo(("\n" if caught else "") + table)
        if left_out:
            metric = _metric(summary.columns, summary.rows)
            click.echo(
                f"({f'{metric}: mean ± 1σ; ' if metric else ''}{left_out} more columns, "
                "the estimates: see the report)"
            )
        click.echo("")
    if not as_json:
        failed = [t for t in doc["tasks"] if t["status"] == "failed"]
        first_errors = [t for t in failed if not str(t["error"]).startswith("upstream ")]
        for t in first_errors:
            where = f"{t['stage']} {t['flight']}" if t["flight"] else t["stage"]
            click.echo(f"FAILED {where} ({t['key'][:12]}): {t['error']}")
        if any(" is corrupt: " in str(t["error"]) for t in failed):
            click.echo(
                "corrupt entries in the store: `aeroid verify --remove` removes them "
                "and the next run recomputes them"
            )
        elsewhere = doc["by_another_run"]
        by_another = f"{elsewhere} computed by another run, " if elsewhere else ""
        click.echo(
            f"{doc['computed']} computed, {doc['cached']} cached, {by_another}"
            f"{doc['failed']} failed in {summary.seconds['total']:.1f} s"
        )
        if doc["report"]:
            click.echo(f"report: {doc['report']}")
        if doc.get("report_html"):
            click.echo(f"report (HTML, with the figures): {doc['report_html']}")
    if summary.report_error:
        click.echo(f"error: {summary.report_error}", err=True)
    sys.exit(1 if doc["failed"] or summary.report_error else 0)


def _status_json(n_stored: int, where: str, tasks: list[Any], stored: list[bool]) -> str:
    """``json.dumps(doc, indent=2)`` of the status document, with each task's lines
    written from a template: the indenting encoder, in Python, took seconds for a
    campaign of 100,000 flights."""
    text = json.encoder.encode_basestring_ascii  # json.dumps's own, as it escapes
    row = '    {{\n      "stage": {},\n      "flight": {},\n      "key": {},\n      "status": "{}"\n    }}'
    rows = [
        row.format(
            text(t.step),
            "null" if t.flight is None else text(t.flight),
            text(t.key),
            "stored" if ok else "missing",
        )
        for t, ok in zip(tasks, stored, strict=True)
    ]
    head = json.dumps(
        {"stored": n_stored, "missing": len(stored) - n_stored, "store": where}, indent=2
    )
    listed = "[\n" + ",\n".join(rows) + "\n  ]" if rows else "[]"
    return head[:-2] + ',\n  "tasks": ' + listed + "\n}"


def _status_tasks(cfg: Any, st: Any, allow_imports: bool) -> list[Any]:
    """The campaign's tasks (step, stage, flight, key): the plan the store keeps for
    these very inputs (`plan_cache`), else planned one flight at a time and kept."""
    from .pipeline.plans import plan_cache
    from .pipeline.plans.planning import plan_stream, stored_plan

    if st is not None:
        found = stored_plan(st, cfg, allow_imports=allow_imports)
        if found is not None:
            return found
    stream = plan_stream(cfg, allow_imports=allow_imports)
    tasks = list(plan_cache.rows(stream))
    if st is not None:
        plan_cache.save(st, stream.inputs, tasks)
    return tasks


@main.command()
@click.argument("config", type=click.Path(dir_okay=False))
@click.option(
    "--store", type=click.Path(file_okay=False), help="Result store (overrides the config)."
)
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document on stdout.")
@click.option(
    "--allow-imports",
    is_flag=True,
    help="Allow 'module:attribute' models and metrics (they import and run that code).",
)
@click.option(
    "--all",
    "list_all",
    is_flag=True,
    help=f"List every task (by default a campaign of over {_STATUS_ROWS} tasks is "
    "summarised per step, with its first missing tasks).",
)
def status(
    config: str, store: str | None, as_json: bool, allow_imports: bool, list_all: bool
) -> None:
    """Which tasks of CONFIG are stored and which are missing (computes nothing)."""
    from .errors import AeroidError, ConfigError
    from .pipeline.plans.config import load_config
    from .pipeline.plans.planning import store_argument
    from .pipeline.storage.store import ResultStore, is_store

    try:
        cfg = load_config(config, store=store_argument(store) if store else None)
        location = cfg.store_location
        if not cfg.store_is_url and cfg.store_path.exists() and not cfg.store_path.is_dir():
            raise ConfigError(f"{cfg.source}: store {cfg.store}: is a file, not a folder")
        st = ResultStore(location, create=False) if is_store(location) else None
        tasks = _status_tasks(cfg, st, allow_imports)
    except AeroidError as exc:
        _fail(str(exc))
        return
    in_store = set() if st is None else st.stored((t.stage, t.key) for t in tasks)
    stored = [(t.stage, t.key) in in_store for t in tasks]
    n_stored = sum(stored)
    where = cfg.store_location
    if as_json:
        click.echo(_status_json(n_stored, where, tasks, stored))
        return
    if list_all or len(stored) <= _STATUS_ROWS:
        rows = [
            [t.step, t.flight or "(campaign)", t.key[:12], "stored" if ok else "missing"]
            for t, ok in zip(tasks, stored, strict=True)
        ]
        click.echo(_table(["stage", "flight", "key", "status"], rows))
    else:
        # a large campaign: one row per step, then the first missing tasks (a table of
        # every task would be as long as the campaign)
        counts: dict[str, list[int]] = {}
        for t, ok in zip(tasks, stored, strict=True):
            counts.setdefault(t.step, [0, 0])[0 if ok else 1] += 1
        click.echo(
            _table(
                ["stage", "stored", "missing"],
                [[k, str(a), str(b)] for k, (a, b) in counts.items()],
            )
        )
        missing = [t for t, ok in zip(tasks, stored, strict=True) if not ok]
        if missing:
            shown = [
                [t.step, t.flight or "(campaign)", t.key[:12]] for t in missing[:_MISSING_SHOWN]
            ]
            click.echo(f"\nfirst {len(shown)} of {len(missing)} missing tasks:")
            click.echo(_table(["stage", "flight", "key"], shown))
        click.echo(f"\n{len(stored)} tasks; `aeroid status --all` lists every one")
    click.echo(f"\n{n_stored} stored, {len(stored) - n_stored} missing in {where}")


def _store_options(f: Any) -> Any:
    f = click.option("--store", type=click.Path(file_okay=False), help="The result store.")(f)
    f = click.option(
        "--config", type=click.Path(dir_okay=False), help="A config naming the store."
    )(f)
    return f


@main.command()
@click.argument("key")
@_store_options
def show(key: str, config: str | None, store: str | None) -> None:
    """A stored result's summary and provenance."""
    from .errors import AeroidError

    st = _open_store(config, store)
    try:
        entry = st.find(key)
        meta = st.metadata(entry.key, entry.stage)
        record = st.load(entry.key, entry.stage)
    except AeroidError as exc:
        _fail(str(exc), 1)
        return
    prov = meta.get("provenance", {})
    task = prov.get("task", {})
    click.echo(f"key:     {entry.key}")
    click.echo(f"stage:   {entry.stage} ({meta['record_type']})")
    if task.get("flight"):
        click.echo(f"flight:  {task['flight']}")
    click.echo("")
    summary = getattr(record, "summary", None)
    click.echo(summary() if callable(summary) else repr(record))
    click.echo("\n## Provenance\n")
    doc = meta["task"]
    click.echo(f"- stage version: {doc.get('stage_version')}")
    opts = doc.get("options") or {}
    click.echo(f"- options: {json.dumps(opts, sort_keys=True)}")
    for role, up in (doc.get("upstream") or {}).items():
        ups = up if isinstance(up, list) else [up]
        click.echo(f"- upstream {role}: {', '.join(str(u)[:19] for u in ups)}")
    if doc.get("model"):
        click.echo(f"- model: {doc['model'].get('name')} (version {doc['model'].get('version')})")
    if doc.get("seed"):
        click.echo(f"- seed: {json.dumps(doc['seed'])}")
    if task.get("source"):
        click.echo(f"- source: {json.dumps(task['source'], sort_keys=True)}")
    if prov.get("seconds"):
        line = f"- compute time: {prov['seconds'].get('compute', 0.0):.3f} s"
        if int(prov["seconds"].get("parts") or 0) > 1:
            line += f" in {prov['seconds']['parts']} parallel parts"
        click.echo(line)
    run_options = {k: v for k, v in (task.get("options") or {}).items() if k not in opts}
    if run_options:  # execution-only options: how it ran, not in the key
        click.echo(f"- run with: {json.dumps(run_options, sort_keys=True)}")
    if prov.get("finished"):
        click.echo(f"- finished: {prov['finished']} on {prov.get('host', '?')}")
    if prov.get("versions"):
        click.echo("- versions: " + ", ".join(f"{k} {v}" for k, v in prov["versions"].items()))
    for text in prov.get("warnings", ()):
        click.echo(f"- warning: {text}")


@main.command()
@click.argument("key", required=False)
@_store_options
@click.option("--all", "every", is_flag=True, help="Recompute every entry of the store.")
@click.option("--stage", help="With --all: only the entries of this stage.")
@click.option(
    "--scheduler", metavar="ADDRESS", help="With --all: tcp://HOST:PORT of a dask scheduler."
)
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    help="With --all: worker processes (default: one per core; 0: in this process).",
)
def rerun(
    key: str | None,
    config: str | None,
    store: str | None,
    every: bool,
    stage: str | None,
    scheduler: str | None,
    workers: int | None,
) -> None:
    """Recompute a stored result (or --all) from its recorded inputs and compare bit for bit."""
    from .errors import AeroidError
    from .pipeline.running.rerun import rerun as rerun_entry

    if (key is None) == (not every):
        _fail("give a KEY or --all (not both)")
    if (stage is not None or scheduler is not None or workers is not None) and not every:
        _fail("--stage, --scheduler and --workers go with --all")
    from .pipeline.plans.config import workers_problem

    if problem := workers_problem(workers):
        _fail(f"--workers: {problem}")
    st = _open_store(config, store)
    current = None
    if config is not None:  # the files and code where the config now finds them
        from .pipeline.running.rerun import current_tasks

        try:
            current = current_tasks(config)
        except AeroidError as exc:
            _fail(str(exc))
    if key is not None:
        try:
            identical, lines = rerun_entry(st, key, current=current)
        except AeroidError as exc:
            _fail(str(exc), 1)
            return
        for line in lines:
            click.echo(line)
        sys.exit(0 if identical else 1)
    from ._progress import progress_bar
    from .pipeline.running.executors import executor_for
    from .pipeline.running.rerun import RerunResult, rerun_all

    n = sum(1 for _ in st.entries(stage))
    if stage is not None and not n:
        _fail(f"no {stage} entries in store {st.root}")
    bar = progress_bar(n, desc="rerun", enabled=True, unit="entry")

    def done(result: RerunResult) -> None:
        if bar is not None:
            bar.update(1)

    try:
        results = rerun_all(
            st,
            stage=stage,
            executor=executor_for(scheduler, workers),
            on_done=done,
            current=current,
        )
    except AeroidError as exc:
        _fail(str(exc), 1)
        return
    finally:
        if bar is not None:
            bar.close()
    same = 0
    for r in results:
        same += r.identical
        label = "FAILED" if r.failed else ("bit-identical" if r.identical else "DIFFERS")
        click.echo(f"{label} {r.entry.stage} {r.entry.key}")
        if not r.identical:
            for line in r.lines[1:]:
                click.echo(f"    {line}")
    click.echo(f"{same} of {len(results)} entries bit-identical")
    sys.exit(0 if same == len(results) else 1)


def _config_entries(config: str, st: Any) -> list[tuple[str, str]]:
    """(stage, key) of every stored entry the campaign in `config` plans."""
    from .errors import AeroidError
    from .pipeline.plans.config import load_config
    from .pipeline.plans.planning import plan

    try:
        cfg = load_config(config)
        the_plan = plan(cfg, allow_imports=bool(getattr(cfg, "allow_imports", False)))
    except AeroidError as exc:
        _fail(str(exc))
        raise AssertionError from None  # unreachable
    wanted = list(dict.fromkeys((t.stage, t.key) for t in the_plan.tasks))
    stored = st.stored(wanted)
    return [w for w in wanted if w in stored]


@main.command()
@_store_options
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document on stdout.")
@click.option(
    "--remove",
    is_flag=True,
    help="Remove the corrupt entries, so that the next run recomputes them.",
)
def verify(config: str | None, store: str | None, as_json: bool, remove: bool) -> None:
    """Check the digests of the config's entries (with --store: of every entry); list
    corrupt entries (exit 1 if any)."""
    from .errors import AeroidError

    st = _open_store(config, store, repair=remove)  # --remove also restores a lost marker
    try:
        if config:
            # the config's own entries only: several campaigns may share one store
            mine = _config_entries(config, st)
            n = len(mine)
            found = ((key, st.verify(key, stage)) for stage, key in mine)
            bad = {key: problem for key, problem in found if problem is not None}
        else:
            n = sum(1 for _ in st.entries())
            bad = st.verify_all()
        removed = [key for key in bad if remove and st.remove(st.find(key).stage, key)]
    except AeroidError as exc:  # a linked folder in the store, a read-only store
        _fail(str(exc), 1)
        return
    if as_json:
        doc: dict[str, object] = {"entries": n, "corrupt": bad}
        if remove:
            doc["removed"] = removed
        click.echo(json.dumps(doc, indent=2))
    else:
        for key, problem in bad.items():
            click.echo(f"CORRUPT {key}: {problem}")
        click.echo(f"{n} entries checked, {len(bad)} corrupt")
        if remove:
            click.echo(f"{len(removed)} removed: the next run recomputes them")
        elif bad:
            click.echo("`aeroid verify --remove` removes them; the next run recomputes them")
    sys.exit(1 if bad else 0)


@main.command()
@_store_options
def gc(config: str | None, store: str | None) -> None:
    """Remove temporaries left by crashed runs."""
    from .errors import AeroidError

    st = _open_store(config, store)
    try:
        removed = st.gc()
    except AeroidError as exc:  # a linked folder in the store, a read-only store
        _fail(str(exc), 1)
        return
    for path in removed:
        click.echo(f"removed {path}")
    click.echo(f"{len(removed)} temporaries removed")


if __name__ == "__main__":  # pragma: no cover
    main()
