"""The runner's execution plumbing: chains, start method, record cache, report figures."""

from __future__ import annotations

import gc
import os
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
from test_pipeline_store import flip_a_bit

from aeroid.errors import PipelineError, StoreError
from aeroid.pipeline import ResultStore, open_store, run
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.running import _process as process_mod
from aeroid.pipeline.running import execution as execution_mod
from aeroid.pipeline.running import executors as executors_mod
from aeroid.pipeline.running import runner as runner_mod
from aeroid.pipeline.running._process import start_method as _start_method
from aeroid.pipeline.running.graph import segments as _segments
from aeroid.pipeline.running.runner import n_parts, plan
from aeroid.pipeline.stages import CampaignReport
from aeroid.pipeline.storage.store import record_cache

PNG = b"\x89PNG\r\n\x1a\n"


def _config(tmp: Path, n: int = 3, extra: str = "") -> Path:
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        f"flights: [{{simulated: {{n_flights: {n}, seed: 1, duration: 6.0}}}}]\n"
        "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n"
        "  validate: {}\n  propagate: {metric: natural_frequency, n_samples: 200}\n" + extra
    )
    return cfg


def test_campaign_report_draws_its_figures_as_parts_and_stores_them(tmp_path):
    cfg = _config(tmp_path)
    p = plan(cfg)
    report = p.report_task
    assert report is not None
    # the trend in two halves, text, and sixteen parts drawing every sixteenth flight's figures
    assert n_parts(report) == 3 + 16
    s = run(cfg, workers=0)
    assert s.failed == 0
    rec = open_store(tmp_path / "store").load(report.key, "campaign_report")
    assert isinstance(rec, CampaignReport)
    assert rec.figure_titles == (
        "campaign_trend_0.png",
        "campaign_trend_1.png",
        *(
            f"sim-{i}_{f}.png"
            for i in range(3)
            for f in ("time_histories", "residual_autocorrelation", "identification")
        ),
    )
    for png in rec.figures:
        assert png.dtype == np.uint8 and not png.flags.writeable
        assert png[:8].tobytes() == PNG
    html = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    assert html.count("data:image/png;base64,") == 2 + 3 * 3
    assert f"aeroid campaign report {report.key}" in html
    # the text written by its own part is the text of the unsplit report
    plain_dir = tmp_path / "plain"
    plain_dir.mkdir()
    plain = _config(plain_dir, extra="  campaign_report: {figures: false}\n")
    run(plain, workers=0)
    key = plan(plain).report_task.key
    unsplit = open_store(plain_dir / "store").load(key, "campaign_report")

    def text(markdown: str) -> list[str]:  # without the figures' links
        return [
            ln
            for ln in markdown.splitlines()
            if ln and not ln.startswith("![") and ln != "### Figures"
        ]

    assert text(unsplit.markdown) == text(rec.markdown) and unsplit.rows == rec.rows


def test_the_campaign_report_takes_briefs_not_entries_and_makes_the_same_record(
    tmp_path, monkeypatch
):
    """Each flight's task hands the campaign report what it uses of its result; the
    report then reads entries only to draw each flight's figures, and the record is
    the one made from the store: by a rerun, or with some flights cached."""
    cfg = _config(tmp_path, n=3)
    read: list[tuple[str, int]] = []
    getitem = execution_mod._LazyRecords.__getitem__

    def spy(self, index):
        read.append((self._stage, index))
        return getitem(self, index)

    monkeypatch.setattr(execution_mod._LazyRecords, "__getitem__", spy)
    # the statuses as the executor returns them (a run's ledger keeps no briefs)
    returned: list = []
    real_run = executors_mod.InProcess.run

    def keep(self, *args, **kwargs):
        out = real_run(self, *args, **kwargs)
        returned.extend(out)
        return out

    monkeypatch.setattr(executors_mod.InProcess, "run", keep)
    s = run(cfg, workers=0)
    assert s.failed == 0
    assert read and {i for _, i in read} == {0, 1, 2}
    assert {st for st, _ in read} <= {"load", "identify", "validate"}  # the figures' inputs
    by_step = {}
    for st in returned:
        by_step.setdefault(st["step"], []).append(sorted(st.get("briefs", {})))
    assert by_step["load"] == [["campaign_report/data"]] * 3
    assert by_step["identify"] == [["campaign_report/identification"]] * 3
    assert by_step["report"] == [["campaign_report/reports"]] * 3
    store = open_store(tmp_path / "store")
    key = plan(cfg).report_task.key
    digest = store.metadata(key)["content_digest"]
    # made from the stored entries alone: the same bits
    same, _ = runner_mod.rerun(store, key)
    assert same
    # one flight's report recomputed, the other flights' results cached
    flight_report = next(st["key"] for st in s.statuses.values() if st["step"] == "report")
    assert store.remove("campaign_report", key) and store.remove("report", flight_report)
    read.clear()
    again = run(cfg, workers=0)
    assert again.count("computed") == 2 and again.failed == 0
    assert {i for _, i in read} == {0, 1, 2}
    assert open_store(tmp_path / "store").metadata(key)["content_digest"] == digest


def test_figures_off_gives_an_unsplit_report_without_figures(tmp_path):
    cfg = _config(tmp_path, extra="  campaign_report: {figures: false}\n")
    p = plan(cfg)
    assert p.report_task is not None and n_parts(p.report_task) == 1
    run(cfg, workers=0)
    rec = open_store(tmp_path / "store").load(p.report_task.key, "campaign_report")
    assert rec.figures == () and rec.figure_titles == ()
    assert "data:image/png" not in (tmp_path / "out" / "report.html").read_text()


def test_chains_group_each_flights_consecutive_steps(tmp_path):
    cfg = _config(
        tmp_path,
        extra="  infer:\n    n_walkers: 8\n    n_steps: 20\n    n_ensembles: 2\n"
        "    parameters: {M_q: {normal: [-2.0, 2.0]}}\n",
    )
    p = plan(cfg)
    chains = _segments(p.tasks)
    # per flight: [load, identify, validate, propagate] then [infer (split), report]
    flights = [c for c, _ in chains if c[0].flight is not None]
    assert [[t.step for t in c] for c in flights[:2]] == [
        ["load", "identify", "validate", "propagate"],
        ["infer", "report"],
    ]
    assert all(split is c[0] for c, split in chains if split is not None)
    assert [t.step for t in chains[-1][0]] == ["campaign_report"]
    assert sum(len(c) for c, _ in chains) == len(p.tasks)


def test_worker_start_method(monkeypatch):
    from aeroid._threads import wait_background

    # a compilation an earlier test queued imports JAX in the background: let it finish
    # first, or it may put `jax` back into sys.modules under the checks below
    assert wait_background(timeout=120)
    monkeypatch.delenv("AEROID_START_METHOD", raising=False)
    monkeypatch.delitem(sys.modules, "jax", raising=False)
    # an earlier test in this worker may have started JAX's backends: hide them too
    monkeypatch.delitem(sys.modules, "jax._src.xla_bridge", raising=False)
    expected = "fork" if sys.platform.startswith("linux") else "spawn"
    assert _start_method() == expected
    monkeypatch.setitem(sys.modules, "jax", object())
    assert _start_method() == "spawn"  # a JAX that does not say it has not started
    bridge = types.SimpleNamespace(_backends={})
    monkeypatch.setitem(sys.modules, "jax._src.xla_bridge", bridge)
    assert _start_method() == expected  # imported, no backend yet: no threads to fork
    bridge._backends["cpu"] = object()
    assert _start_method() == "spawn"  # JAX's threads must not be forked
    monkeypatch.setenv("AEROID_START_METHOD", "forkserver")
    assert _start_method() == "forkserver"


def test_an_entry_altered_between_runs_is_caught_by_the_next_run(tmp_path):
    """Records are cached within a run only: the next run in the same process reads again."""
    cfg = _config(tmp_path, n=2)
    assert run(cfg, workers=0).failed == 0
    p = plan(cfg)
    ident = next(t for t in p.tasks if t.step == "identify")
    store = ResultStore(tmp_path / "store")
    flip_a_bit(store.path_for("identify", ident.key))
    # a changed validate option recomputes validate, which reads the altered identify entry
    cfg.write_text(cfg.read_text().replace("  validate: {}", "  validate: {confidence: 0.9}"))
    s = run(cfg, workers=0)
    bad = [v for v in s.statuses.values() if v["status"] == "failed"]
    assert any(v["step"] == "validate" and "corrupt" in v["error"] for v in bad)


def test_the_record_cache_is_scoped(tmp_path):
    store = ResultStore(tmp_path / "s")
    task = {"k": 1}
    key = sha256_hex(canonical_json(task))
    rec = CampaignReport("t", "text", ("a",), ("flight",), (("a",),))
    record_cache("run-1")
    try:
        store.commit("campaign_report", key, rec, task=task)
        cached = store.load(key, "campaign_report")
        assert store.load(key, "campaign_report") is cached  # served from memory
        store.path_for("campaign_report", key).unlink()
        assert store.load(key, "campaign_report") is cached  # this run committed it
        record_cache("run-2")
        with pytest.raises(StoreError, match="not in store"):
            store.load(key, "campaign_report")
    finally:
        record_cache(None)


def test_detailed_figures_fall_back_to_the_first_identified_flight(tmp_path):
    """The first flight fails: its figure parts defer, and the report draws flight f01's."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_cli import write_flight

    flights = tmp_path / "flights"
    flights.mkdir()
    # right header (the pre-flight checks read headers only), unreadable data
    (flights / "f00.csv").write_text("time,alpha,q,elevator\n0.0,x,0,0\n0.1,y,0,0\n")
    for i in (1, 2):
        write_flight(flights / f"f{i:02d}.csv", i)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        "flights: ['flights/*.csv']\n"
        "stages:\n  identify: {parameters: [M_alpha, M_q, M_delta]}\n  validate: {}\n"
    )
    s = run(cfg, workers=0)
    assert s.failed > 0  # f00's chain; the report is written, never cached
    html = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    assert "f01: measured and model outputs" in html and "f01: residuals" in html
    assert "f02: measured and model outputs" in html
    assert "f00: measured and model outputs" not in html
    assert html.count("data:image/png;base64,") == 2 + 2 * 3  # and the trend's two halves
    assert "estimates across flights (1)" in html and "estimates across flights (2)" in html


def test_an_unchanged_rerun_draws_nothing_and_does_not_import_matplotlib(tmp_path):
    # matplotlib costs about a second to import: a rerun that only checks the store
    # must not pay it (the report's figures are stored with the campaign report)
    import subprocess

    cfg = _config(tmp_path, n=2)
    run(cfg, workers=0)
    code = (
        "import sys\n"
        "from aeroid.pipeline import run\n"
        f"s = run({str(cfg)!r})\n"
        "print(s.count('computed'), s.count('cached'), 'matplotlib' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path
    )
    computed, cached, imported = out.stdout.split()
    assert computed == "0" and int(cached) > 0
    assert imported == "False"


BLAS_PROBE = """
from dataclasses import dataclass
from aeroid.pipeline import Pipeline, Stage, Step, register_record, register_stage
from aeroid.pipeline.plans.config import Options


@register_record
@dataclass(frozen=True, eq=False)
class WorkerState:
    threads: int
    pid: int
    os_threads: int


class ProbeOptions(Options):
    pass


def probe(ctx):
    import os

    from threadpoolctl import threadpool_info

    # counted before threadpoolctl looks: the threads this worker started on its own
    tasks = len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else -1
    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    return WorkerState(max(blas, default=-1), os.getpid(), tasks)


register_stage(Stage("blas_probe", "1", ProbeOptions, "blas_probe_mod:WorkerState", probe,
                     uses_model=False))
pipeline = Pipeline("probe", flight_steps=(Step("load"), Step("blas_probe")), campaign_steps=())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers on Linux")
def test_embedded_workers_are_processes_with_one_blas_thread(tmp_path, monkeypatch):
    (tmp_path / "blas_probe_mod.py").write_text(BLAS_PROBE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delenv("AEROID_START_METHOD", raising=False)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nstore: store\npipeline: blas_probe_mod:pipeline\n"
        "flights: [{simulated: {n_flights: 2, seed: 1, duration: 2.0}}]\n"
        "stages: {blas_probe: {}}\n"
    )
    from threadpoolctl import threadpool_info, threadpool_limits

    with threadpool_limits(limits=2):  # what forked workers would inherit, unpinned
        s = run(cfg, workers=2)
        # the run pins this process's BLAS while it forks, and gives its limits back
        assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {2}
    assert s.failed == 0
    store = open_store(tmp_path / "store")
    states = [store.load(t.key, t.stage) for t in s.plan.tasks if t.step == "blas_probe"]
    assert [w.threads for w in states] == [1, 1]
    assert all(w.pid != os.getpid() for w in states)
    if _start_method() == "fork":
        # no BLAS threads (a forked worker that sets its own count starts them, each
        # spinning for a while): the main thread, the one that watches the parent and
        # the one that renews the task's claim on the store while it computes
        assert [w.os_threads for w in states] == [3, 3]


@pytest.mark.slow
def test_spawned_workers_pin_their_own_blas_and_store_the_same_bytes(tmp_path, monkeypatch):
    (tmp_path / "blas_probe_mod.py").write_text(BLAS_PROBE)
    monkeypatch.syspath_prepend(str(tmp_path))
    stores = {}
    # JAX loaded by an earlier test must not be forked: then spawn alone
    can_fork = sys.platform.startswith("linux") and "jax" not in sys.modules
    for method in ("spawn", "fork") if can_fork else ("spawn",):
        monkeypatch.setenv("AEROID_START_METHOD", method)
        cfg = tmp_path / f"{method}.yaml"
        cfg.write_text(
            f"model: short_period\nstore: {method}-store\npipeline: blas_probe_mod:pipeline\n"
            "flights: [{simulated: {n_flights: 2, seed: 1, duration: 2.0}}]\n"
            "stages: {blas_probe: {}}\n"
        )
        s = run(cfg, workers=2)
        assert s.failed == 0
        store = open_store(tmp_path / f"{method}-store")
        probes = [store.load(t.key, t.stage) for t in s.plan.tasks if t.step == "blas_probe"]
        assert [w.threads for w in probes] == [1, 1]
        assert all(w.pid != os.getpid() for w in probes)
        loads = {t.key: t.stage for t in s.plan.tasks if t.step == "load"}
        stores[method] = {k: store.metadata(k, st)["digests"] for k, st in loads.items()}
    if len(stores) == 2:
        assert stores["spawn"] == stores["fork"]


def test_flights_from_csv_parquet_and_mat_files_give_the_same_numbers(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    import scipy.io

    from aeroid.models.catalog import short_period_flight

    d = short_period_flight(seed=3)
    columns = {"time": d.time, **{n: d[n] for n in d.names}}
    folder = tmp_path / "flights"
    folder.mkdir()
    rows = np.column_stack(list(columns.values()))
    (folder / "a.csv").write_text(
        ",".join(columns) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows)
    )
    pq.write_table(pa.table(columns), folder / "b.parquet")
    scipy.io.savemat(folder / "c.mat", columns)
    cfg = tmp_path / "files.yaml"
    cfg.write_text(
        "model: short_period\nstore: store\n"
        "flights: ['flights/*.csv', 'flights/*.parquet', 'flights/*.mat']\n"
        "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n  validate: {}\n"
    )
    s = run(cfg, workers=0)
    assert s.failed == 0, s.to_json()
    assert len(s.plan.flights) == 3
    store = open_store(tmp_path / "store")
    by_step: dict[str, list[str]] = {}
    for t in s.plan.tasks:
        by_step.setdefault(t.step, []).append(t.key)
    # three files, three load keys (a load key hashes the file's bytes) ...
    assert len(set(by_step["load"])) == 3
    loaded = [store.load_arrays(k) for k in by_step["load"]]
    for other in loaded[1:]:  # ... holding the same numbers
        assert other.keys() == loaded[0].keys()
        assert all(other[n].tobytes() == loaded[0][n].tobytes() for n in other)
    fits = [store.load(k) for k in by_step["identify"]]
    assert all(dict(f.parameters) == dict(fits[0].parameters) for f in fits)


def test_stages_after_the_fit_start_from_its_initial_state(tmp_path):
    """With `estimate_x0`, filter, frequency and sensitivities simulate the flight from the
    state the fit estimated (the library takes it from the fit), not from the first
    noisy samples."""
    import aeroid
    from aeroid.models import catalog

    filter_noise = {
        "process_noise": {"alpha": 1.0e-8, "q": 1.0e-8},
        "measurement_noise": {"alpha": 2.5e-5, "q": 1.0e-4},
    }
    extra = (
        "  filter: {process_noise: {alpha: 1.0e-8, q: 1.0e-8},"
        " measurement_noise: {alpha: 2.5e-5, q: 1.0e-4}}\n"
        # simulated: the exact response (the stage's default here) has no initial state
        "  frequency: {frequency_range: [0.2, 3.0], model_response: simulated}\n"
        "  sensitivities: {noise: {alpha: 0.005, q: 0.01}}\n"
    )
    cfg = _config(tmp_path, n=1, extra=extra)
    cfg.write_text(cfg.read_text().replace("M_delta]}", "M_delta], estimate_x0: true}"))
    p = plan(cfg)
    assert run(cfg, workers=0).failed == 0
    store = open_store(tmp_path / "store")
    by_step = {t.step: store.load(t.key, t.stage) for t in p.tasks if t.flight is not None}
    data, fit = by_step["load"], by_step["identify"]
    x0 = dict(fit.initial_states[0])
    first = {c: float(data[c][0]) for c in ("alpha", "q")}
    assert all(abs(x0[c] - first[c]) > 1e-6 for c in first)  # estimated
    model = catalog.short_period()
    for start, same in ((x0, True), (first, False)):
        filt = aeroid.filter_states(model, data, fit, x0=start, **filter_noise)
        with pytest.warns(UserWarning, match="too few coherent"):  # a 6 s record
            freq = aeroid.frequency_response(
                model, data, fit, frequency_range=(0.2, 3.0), x0=start, min_coherent=1
            )
        sens = aeroid.sensitivities(
            model,
            data,
            None,
            values=fit,
            noise={"alpha": 0.005, "q": 0.01},
            x0=start,
        )
        pairs = (
            (by_step["filter"].smoothed_states, filt.smoothed_states),
            (by_step["frequency"].channels[0].model_magnitude, freq.channels[0].model_magnitude),
            # the simulated outputs: at the fit its estimated start is a nuisance the
            # information leaves out, while a start given is held known
            (by_step["sensitivities"].outputs, sens.outputs),
        )
        assert all(np.array_equal(a, b) for a, b in pairs) is same


def test_stages_after_a_fit_with_measured_initial_state_are_unchanged(tmp_path):
    """Without estimation the fit's initial state is the first sample, bit for bit, so the
    stages compute what the library's own default gives."""
    import aeroid
    from aeroid.models import catalog

    cfg = _config(
        tmp_path,
        n=1,
        extra="  frequency: {frequency_range: [0.2, 3.0]}\n",
    )
    fields = "parameters: [Z_alpha, M_alpha, M_q, M_delta]"
    cfg.write_text(cfg.read_text().replace(fields, fields + ", estimate_x0: false"))
    p = plan(cfg)
    assert run(cfg, workers=0).failed == 0
    store = open_store(tmp_path / "store")
    by_step = {t.step: store.load(t.key, t.stage) for t in p.tasks if t.flight is not None}
    data, fit = by_step["load"], by_step["identify"]
    assert dict(fit.initial_states[0]) == {c: float(data[c][0]) for c in ("alpha", "q")}
    with pytest.warns(UserWarning, match="too few coherent"):  # as the stage warned
        plain = aeroid.frequency_response(
            catalog.short_period(), data, fit, frequency_range=(0.2, 3.0), model_response="auto"
        )
    # the stage's default: the linear model's exact transfer function
    assert by_step["frequency"].model_response == plain.model_response == "exact"
    for got, want in zip(by_step["frequency"].channels, plain.channels, strict=True):
        np.testing.assert_array_equal(got.model_magnitude, want.model_magnitude)


def test_a_store_or_report_that_cannot_be_written_is_refused_before_anything_runs(tmp_path):
    from aeroid.errors import ConfigError

    cfg = _config(tmp_path, n=2)
    (tmp_path / "afile").write_text("not a folder")
    with pytest.raises(StoreError, match=r"store .*afile: is a file, not a folder"):
        run(cfg, store=tmp_path / "afile", workers=0)
    with pytest.raises(StoreError, match=r"store .*afile/below: cannot create it"):
        run(cfg, store=tmp_path / "afile" / "below", workers=0)
    text = cfg.read_text()
    cfg.write_text(text.replace("report: out/report.md", "report: afile/report.md"))
    with pytest.raises(ConfigError, match=r"c.yaml: report: cannot make .*afile"):
        run(cfg, workers=0)
    (tmp_path / "folder").mkdir()
    cfg.write_text(text.replace("report: out/report.md", "report: folder"))
    with pytest.raises(ConfigError, match=r"c.yaml: report: .*folder is a folder"):
        run(cfg, workers=0)
    assert not list((tmp_path / "store").glob("*/*"))  # nothing computed


def test_a_missing_flight_file_or_a_folder_is_refused_before_anything_runs(tmp_path):
    from aeroid.errors import ConfigError
    from aeroid.models.catalog import short_period_flight

    d = short_period_flight(seed=1, duration=4.0)
    rows = np.column_stack([d.time, *(d[n] for n in d.names)])
    np.savetxt(
        tmp_path / "ok.csv", rows, delimiter=",", header=",".join(["time", *d.names]), comments=""
    )
    (tmp_path / "adir").mkdir()
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nstore: store\nflights: [ok.csv, gone.csv, adir]\n")
    # the pre-flight checks list both, before any flight runs
    with pytest.raises(ConfigError, match=r"(?s)flights\[1\]: no such file: .*gone.csv.*adir"):
        run(cfg, workers=0)
    assert not list((tmp_path / "store").glob("*/*"))


CRASHING_MODEL = """
import os

import numpy as np

import aeroid
from aeroid.models.catalog import short_period


def _dynamics(t, x, u, p):
    # fitted to the wild flight (its elevator x 1e4), M_delta heads for -7e-4: there this
    # "native code" crashes, as far as the worker can tell
    if abs(p["M_delta"]) < 0.01:
        os._exit(3)
    return np.array([p["Z_alpha"] * x[0] + x[1], p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0]])


base = short_period()
model = aeroid.Model(states=["alpha", "q"], controls=["elevator"], parameters=dict(base.parameters),
                     dynamics=_dynamics, name="crashing")
"""


@pytest.mark.parametrize(
    "scheduler", ["embedded", pytest.param("distributed", marks=pytest.mark.slow)]
)
def test_a_worker_that_dies_fails_its_flight_at_the_step_that_killed_it(tmp_path, scheduler):
    from aeroid.models.catalog import short_period_flight

    (tmp_path / "crashing_model.py").write_text(CRASHING_MODEL)
    for name, scale in (("good", 1.0), ("wild", 1e4)):
        d = short_period_flight(seed=1, duration=4.0)
        cols = [d.time, *(d[n] * (scale if n == "elevator" else 1.0) for n in d.names)]
        np.savetxt(
            tmp_path / f"{name}.csv",
            np.column_stack(cols),
            delimiter=",",
            header=",".join(["time", *d.names]),
            comments="",
        )
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: crashing_model:model\nstore: store\nflights: [good.csv, wild.csv]\n"
        "stages:\n  identify: {parameters: [M_q, M_delta]}\n  validate: {}\n"
    )
    if scheduler == "embedded":
        s = run(cfg, workers=2, allow_imports=True)
    else:
        import logging

        from dask.distributed import LocalCluster

        # a dask.distributed cluster of its own: spawned workers, which find the model
        # beside the config as the embedded ones do
        with LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        ) as cluster:
            s = run(cfg, scheduler=cluster.scheduler_address, allow_imports=True)
    by = {(st["step"], st["flight"]): st for st in s.statuses.values()}
    assert by[("load", "wild")]["status"] == "computed"  # stored before the worker died
    assert by[("identify", "wild")]["status"] == "failed"
    assert "the worker process died while running identify" in by[("identify", "wild")]["error"]
    assert by[("validate", "wild")]["error"] == "not run: the worker died at identify"
    if scheduler == "embedded":
        # the other flight, stopped with the pool, was run again alone and is intact (Dask's
        # own cluster may kill a task queued beside the crash: it fails the same way)
        # (what its first worker committed before the pool stopped: computed by this run)
        assert all(st["status"] == "computed" for (_, f), st in by.items() if f == "good")
    # the campaign report is written whatever died
    report = next(st for st in s.statuses.values() if st["step"] == "campaign_report")
    assert report["status"] == "computed" and s.report_path.is_file()
    assert "wild" in s.report_path.read_text()
    store = open_store(tmp_path / "store")
    assert store.verify_all() == {} and store.temporaries() == []


_execute_chain = execution_mod.execute_chain


def _chain_that_fails_outside_its_tasks(tasks, *args, **kwargs):
    if tasks[0].flight == "sim-1":
        raise RuntimeError("lost in transit")
    return _execute_chain(tasks, *args, **kwargs)


def test_an_error_outside_a_chains_tasks_fails_that_flight_only(tmp_path, monkeypatch):
    monkeypatch.setattr(execution_mod, "execute_chain", _chain_that_fails_outside_its_tasks)
    s = run(_config(tmp_path), workers=2)
    bad = [st for st in s.statuses.values() if st["flight"] == "sim-1"]
    assert bad and all(st["status"] == "failed" for st in bad)
    assert bad[0]["error"] == "the worker failed while running load (RuntimeError: lost in transit)"
    assert bad[1]["error"] == "not run: the worker failed at load"
    good = [st for st in s.statuses.values() if st["flight"] not in ("sim-1", None)]
    assert good and all(st["status"] == "computed" for st in good)
    assert s.report_path is not None and s.report_path.is_file()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers on Linux")
def test_a_forking_pool_leaves_the_garbage_collector_as_it_found_it(monkeypatch):
    # the pool freezes this process's objects while it lives (so forked workers do not
    # copy the planner's pages), and unfreezes them after; a caller's own freeze stays.
    # (The suite loads JAX, where a run would spawn: the pool is made to fork here, and
    # its worker runs nothing but os.getpid.)
    monkeypatch.setenv("AEROID_START_METHOD", "fork")
    assert gc.get_freeze_count() == 0
    with process_mod.process_pool(1) as pool:
        assert gc.get_freeze_count() > 0
        assert pool.submit(os.getpid).result() != os.getpid()
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        mine = gc.get_freeze_count()
        with process_mod.process_pool(1) as pool:
            pool.submit(os.getpid).result()
        # (frozen objects let go of meanwhile are freed as usual: the count may drop a little)
        assert gc.get_freeze_count() > mine // 2 > 0
    finally:
        gc.unfreeze()


def test_a_pool_that_will_not_start_is_reported_not_retried_forever(tmp_path, monkeypatch):
    def no_pool(n):
        raise OSError("Too many open files")

    monkeypatch.setattr(process_mod, "process_pool", no_pool)
    with pytest.raises(PipelineError, match="could not run: OSError: Too many open files"):
        run(_config(tmp_path), workers=2)


def _chain_that_notes_its_start(tasks, *args, **kwargs):
    started = time.time()
    out = _execute_chain(tasks, *args, **kwargs)
    out[0] = out[0].replace(warnings=(f"started {started!r}",))
    return out


def test_the_embedded_cluster_starts_the_flights_in_order_the_first_first(tmp_path, monkeypatch):
    # the report's detailed figures wait on the first flight only: started first, they
    # are drawn while the other flights run, not alone after the last one (Dask's own
    # order for nodes that wait on nothing follows string hashes, new in each process)
    monkeypatch.setattr(execution_mod, "execute_chain", _chain_that_notes_its_start)
    s = run(_config(tmp_path, n=8, extra="  campaign_report: {figures: false}\n"), workers=2)
    assert s.failed == 0
    heads = [st for st in s.statuses.values() if st.warnings and st.flight]
    order = [st.flight for st in sorted(heads, key=lambda st: float(st.warnings[0].split()[1]))]
    assert len(order) == 8
    # two workers start two flights at a time, then each the next when it is free (which
    # of them stamps its start first is a race, so a flight may be a place or two off)
    assert set(order[:2]) == {"sim-0", "sim-1"}
    assert all(abs(order.index(f"sim-{i}") - i) <= 2 for i in range(8)), order


def test_a_run_on_worker_processes_leaves_no_thread_or_process_behind(tmp_path):
    # the pool is shut down before the run returns: nothing of it outlives the run
    import multiprocessing
    import threading

    before = set(threading.enumerate())
    s = run(_config(tmp_path, n=2), workers=2)
    assert s.failed == 0 and s.count("computed") > 0
    assert [t for t in threading.enumerate() if t not in before] == []
    assert multiprocessing.active_children() == []


def test_a_script_that_exits_right_after_a_run_leaves_stderr_clean(tmp_path):
    cfg = _config(tmp_path, n=2, extra="  campaign_report: {figures: false}\n")
    for i in range(3):  # a new store each time: a pool to close
        script = (
            "import sys\nfrom aeroid.pipeline import run\n"
            f"s = run({str(cfg)!r}, store={str(tmp_path / f's{i}')!r}, workers=2)\n"
            "sys.exit(s.failed or s.count('computed') == 0)\n"
        )
        res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
        assert res.returncode == 0 and res.stderr == "", res.stderr


def test_a_campaign_task_run_whole_is_handed_out_before_other_ready_nodes():
    ready = executors_mod._WholeFirst(["b", "database", "a"], {"database"})
    ready.append("part1")
    # popped from the end, as Dask pops, the database before every other node
    assert [ready.pop() for _ in range(2)] == ["database", "part1"]
    ready.append("database")
    ready.append("part2")
    assert [ready.pop() for _ in range(4)] == ["database", "part2", "a", "b"]
    assert not ready
