"""One task's way through the campaign engine's seams (plan, run, store, stages), followed
with `sys.setprofile` (see `_engine_path`): after the run hands the task over, each seam
is entered once, and none is entered again after it was left."""

from __future__ import annotations

from pathlib import Path

import pytest
from _engine_path import Stop, Way, follow

from aeroid.pipeline import open_store
from aeroid.pipeline.stages import STAGES

# the engine's seams are the subpackages of aeroid/pipeline; the modules left in
# aeroid/pipeline itself, and the stage contract (`aeroid.pipeline.stages`), are the
# vocabulary every seam shares (content keys, the options base, pipeline definitions, the
# vehicle model a task names), which belongs to no seam
SEAMS = ("plans", "running", "storage", "stages")
SHARED = {"keys", "_options", "definition", "_code", "vehicle"}
CONTRACT = "aeroid.pipeline.stages"


def seam_of(module: str) -> str | None:
    """The seam of an engine module: the subpackage it lives in; None for the shared
    vocabulary."""
    parts = module.split(".")
    if module == CONTRACT or len(parts) < 3 or parts[2] not in SEAMS:
        return None
    return parts[2]


def _engine_modules() -> list[str]:
    engine = Path(__file__).resolve().parents[1] / "aeroid" / "pipeline"
    out = []
    for p in sorted(engine.rglob("*.py")):
        parts = ["aeroid", *p.relative_to(engine.parent).with_suffix("").parts]
        out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def _config(tmp: Path) -> Path:
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        "flights: [{simulated: {n_flights: 2, seed: 1, duration: 4.0}}]\n"
        "stages:\n  identify: {parameters: [M_q, M_delta]}\n"
        "  campaign_report: {figures: false}\n",
        encoding="utf-8",
    )
    return cfg


@pytest.fixture(scope="module")
def identify_way(tmp_path_factory: pytest.TempPathFactory) -> tuple[Way, object, Path]:
    tmp = tmp_path_factory.mktemp("way")
    # the second flight's fit: the run's caches are warm, as for most of a campaign's tasks
    way, summary = follow(_config(tmp), "identify", seam_of, flight_index=1)
    return way, summary, tmp


def test_every_engine_module_has_a_seam_or_is_shared():
    seams = {m: seam_of(m) for m in _engine_modules()}
    assert set(seams.values()) == {None, *SEAMS}
    # beside the seams only the shared vocabulary: a new module goes into a seam
    assert {m for m, seam in seams.items() if seam is None} == {
        "aeroid.pipeline",
        CONTRACT,
        *(f"aeroid.pipeline.{name}" for name in SHARED),
    }
    # the seams import the vocabulary, never the other way round
    from test_house import import_graph

    graph = import_graph()
    shared = [m for m, seam in seams.items() if seam is None and m != "aeroid.pipeline"]
    assert not [(m, i) for m in shared for i in graph[m] if seam_of(i) is not None]


def test_the_way_finder_sees_a_seam_entered_again():
    def entry(seam: str, below: frozenset[str] = frozenset({"running"})) -> Stop:
        return Stop(f"m.{seam}", "call", True, seam, True, below)

    back = Stop("m.running", "return", True, "running")
    once = Way([entry("storage"), back, entry("stages"), back])
    assert once.reentered() == [] and once.entries() == ["storage", "stages"]
    twice = Way([entry("storage"), back, entry("stages"), back, entry("storage"), back])
    assert twice.reentered() == ["storage"]
    # called back while one of its frames waits below: never left
    nested = Way([entry("storage"), entry("running", frozenset({"running", "storage"}))])
    nested.stops.append(entry("storage", frozenset({"running", "storage"})))
    assert nested.reentered() == []


def test_a_task_passes_each_seam_once_from_the_run_to_its_entry(identify_way):
    way, summary, _ = identify_way
    assert summary.failed == 0
    print("\nthe task's own execution:", way.summary(True), way.counts(True))
    print("its whole way from run(config):", way.summary(None))
    assert way.reentered(True) == []
    entered = [s for s in way.part(True) if s.entry]
    # the run calls the store once (`commits.put`): it claims, has the run make the
    # record under the claim, writes the entry, releases
    called_by_run = [s for s in entered if s.on_stack == {"running"}]
    assert [(s.seam, s.function) for s in called_by_run] == [("storage", "put")]
    # the stage's work is one call into the stages seam (`work.perform`), inside `put`
    into_stages = [s for s in entered if s.seam == "stages"]
    assert [s.function for s in into_stages] == ["perform"]
    assert {"storage", "running"} <= into_stages[0].on_stack
    # the task carries what the run needs: the plan seam is not visited
    assert not [s for s in way.part(True) if s.seam == "plans"]


# the run itself: `run` and the streamed run it drives (the ledger calls no seam). The
# executor's modules (`executors`, `graph`, `execution`) call the seams for the tasks of
# each window it is handed: a task's `execute_task` (its `put`, asserted above), a
# campaign task's parts counted through its stage, the records cached for a window let go;
# those calls are the tasks' work, made again for every window, and are not the run's.
RUN = {"aeroid.pipeline.running.runner", "aeroid.pipeline.running.streaming"}
EXECUTOR = {f"aeroid.pipeline.running.{m}" for m in ("executors", "graph", "execution")}
# what the run may ask a seam again after its one call there, a task at a time: the plan
# stream `plan_run` handed back, read as the run goes (planned a flight at a time, so the
# run's memory stays bounded per flight; at its end the stream keeps the plan's keys), and
# the store's one look, asked whether a task is stored (`Lookup.find`)
ASKED_A_TASK_AT_A_TIME = {("plans", "_kept"), ("storage", "Lookup.find")}


def reentered_by_run(way: Way) -> list[tuple[str, str]]:
    """The run's calls into a seam it had called before, less the asks above."""
    seen: set[str] = set()
    again = []
    for seam, function in way.calls_from(RUN):
        if seam in seen and (seam, function) not in ASKED_A_TASK_AT_A_TIME:
            again.append((seam, function))
        seen.add(seam)
    return again


def test_the_whole_way_from_run_passes_each_seam_once(identify_way):
    way, summary, _ = identify_way
    print("\nits whole way from run(config):", way.summary(None))
    assert reentered_by_run(way) == []
    calls = way.calls_from(RUN)
    # the plan seam once first (the config checked, the stream, the report path checked,
    # the store opened with its look), the stages seam once last (the store's index, the
    # database's files, the report)
    assert calls[0] == ("plans", "plan_run")
    assert calls[-1] == ("stages", "write_run_outputs")
    assert set(calls[1:-1]) == ASKED_A_TASK_AT_A_TIME
    # the look is asked once a task; the stream once a task and once more to end
    n = len(summary.plan.tasks)
    assert calls.count(("storage", "Lookup.find")) == n
    assert calls.count(("plans", "_kept")) == n + 1
    # the executor's own calls, for each window's tasks: parts counted through their stage
    # (`work.options_of`, the stage's `parts`), the window's cached records let go
    executor = way.calls_from(EXECUTOR)
    assert {seam for seam, _ in executor} == {"stages", "storage"}
    assert {f for seam, f in executor if seam == "storage"} == {"record_cache"}
    # the store is opened once, inside the plan seam's call, and never by the run
    opened = [
        s for s in way.part(False) if s.kind == "call" and s.function == "ResultStore.__init__"
    ]
    assert len(opened) == 1 and "plans" in opened[0].on_stack


def test_the_way_finder_sees_the_run_call_a_seam_again():
    def call(seam: str, function: str) -> Stop:
        below = frozenset({"running"})
        return Stop(f"m.{seam}", "call", False, seam, True, below, function, min(RUN))

    back = Stop("m.running", "return", False, "running")
    once = Way([call("plans", "plan_run"), back, call("storage", "Lookup.find"), back])
    once.stops += [call("storage", "Lookup.find"), back, call("stages", "write"), back]
    assert reentered_by_run(once) == []
    # today's startup asked the plan seam, the store and the stages seam apart
    twice = Way([call("plans", "load_config"), back, call("plans", "plan_stream"), back])
    twice.stops += [call("storage", "ResultStore.__init__"), back, call("storage", "look_up")]
    assert reentered_by_run(twice) == [("plans", "plan_stream"), ("storage", "look_up")]


def test_briefs_made_before_the_commit_equal_those_made_from_the_entry(tmp_path, monkeypatch):
    # `work.perform` makes a result's briefs from the record it computed; the campaign
    # task would make them from the stored entry: they must be the same
    from aeroid.pipeline import run
    from aeroid.pipeline.running import executors

    returned: list = []  # the statuses as the executor returns them (the ledger keeps none)
    real_run = executors.InProcess.run

    def keep(self, *args, **kwargs):
        out = real_run(self, *args, **kwargs)
        returned.extend(out)
        return out

    monkeypatch.setattr(executors.InProcess, "run", keep)
    summary = run(_config(tmp_path), workers=0)
    assert summary.failed == 0
    store = open_store(tmp_path / "store")
    given = {st["key"]: st.get("briefs", {}) for st in returned}
    seen = 0
    for task in summary.plan.tasks:
        for consumer, role in task.briefs:
            name = f"{consumer}/{role}"
            if name not in given.get(task.key, {}):
                continue
            make = STAGES[consumer].brief
            assert make is not None
            assert given[task.key][name] == make(role, store.load(task.key, task.stage)), name
            seen += 1
    assert seen >= 2  # both flights' fits


def test_a_campaign_task_passes_each_seam_once_too(tmp_path):
    # the campaign report, over every flight (its inputs' briefs handed over, or their
    # records read through the store inside `put`)
    way, summary = follow(_config(tmp_path), "campaign_report", seam_of, flight_index=None)
    assert summary.failed == 0
    assert way.reentered(True) == []
    entered = [s for s in way.part(True) if s.entry]
    assert [(s.seam, s.function) for s in entered if s.on_stack == {"running"}] == [
        ("storage", "put")
    ]
    assert [s.function for s in entered if s.seam == "stages"] == ["perform"]
    assert not [s for s in way.part(True) if s.seam == "plans"]
