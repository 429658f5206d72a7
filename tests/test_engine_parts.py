"""The campaign engine's parts: stage options that follow the library, configs that import
nothing by surprise, reports that overwrite nothing of the user's, rerun on executors."""

from __future__ import annotations

import errno
import importlib
import importlib.util
import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from aeroid.cli import main
from aeroid.errors import ConfigError
from aeroid.pipeline import STAGES, TaskStatus, open_store, plan, run
from aeroid.pipeline.running.executors import InProcess, LocalProcesses
from aeroid.pipeline.running.rerun import rerun_all

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "aeroid" / "pipeline"
# stages whose work is the engine's own: no library function behind them
ENGINE_STAGES = {"campaign_report"}


def _config(tmp: Path, extra: str = "", head: str = "", n: int = 2) -> Path:
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        + head
        + f"flights: [{{simulated: {{n_flights: {n}, seed: 1, duration: 4.0}}}}]\n"
        "stages:\n  identify: {parameters: [M_q, M_delta]}\n  validate: {}\n"
        "  campaign_report: {figures: false}\n" + extra
    )
    return cfg


# -- stage options follow the library's signatures ------------------------------------------


def _library_function(spec: str):
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_stage_option_is_a_keyword_of_its_library_function(name):
    options = STAGES[name].options
    spec = getattr(options, "library", None)
    if name in ENGINE_STAGES:
        assert spec is None
        return
    assert spec, f"{name}: its options name no library function"
    fn = _library_function(spec)
    params = inspect.signature(fn).parameters
    engine_only = getattr(options, "engine_only", frozenset())
    assert engine_only <= set(options.model_fields), engine_only
    for field_name, info in options.model_fields.items():
        if field_name in engine_only:
            continue
        assert field_name in params, f"{name}.{field_name} is not a keyword of {spec}"
        param = params[field_name]
        if info.is_required():
            # required here only where the library requires it too, or takes it positionally
            assert param.default is inspect.Parameter.empty or param.kind in (
                inspect.Parameter.POSITIONAL_OR_KEYWORD,
            ), f"{name}.{field_name}"
        else:
            # None stands for the library's own default
            assert info.default is None or info.default == param.default, (
                f"{name}.{field_name}: default {info.default!r}, library {param.default!r}"
            )


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_built_in_stage_names_the_library_function_it_wraps(name):
    stage = STAGES[name]
    if name in ENGINE_STAGES:
        assert stage.library is None
        return
    assert stage.library == stage.options.library
    assert callable(_library_function(stage.library))


def test_options_built_from_a_signature_take_its_types_and_refuse_other_keys():
    from pydantic import Field

    from aeroid.errors import PipelineError
    from aeroid.pipeline.plans.config import validate_options
    from aeroid.pipeline.stages.signature_options import library_fields

    freq = STAGES["frequency_response"].options
    # types read from `frequency_response`'s signature; bounds the stage's; None: the default
    assert freq.model_fields["frequency_range"].annotation == (tuple[float, float] | None)
    assert freq.model_fields["inputs"].annotation == (list[str] | None)
    assert all(f.default is None for f in freq.model_fields.values())
    assert freq(nperseg=256, frequency_range=[0.2, 3.0]).frequency_range == (0.2, 3.0)
    for bad in ({"nperseg": "long"}, {"nperseg": 4}, {"outputs": "q"}):
        with pytest.raises(ConfigError, match=r"stages\.frequency\.(nperseg|outputs)"):
            validate_options(freq, bad, source="c.yaml", where="stages.frequency")
    with pytest.raises(
        ConfigError, match=r"nprseg: unknown key; allowed keys: .*; did you mean 'nperseg'\?"
    ):
        validate_options(freq, {"nprseg": 256}, source="c.yaml", where="stages.frequency")
    # a keyword the function does not take, or typed `Any` without a type given, is refused
    with pytest.raises(PipelineError, match="takes no keyword 'nperseg'"):
        library_fields("aeroid.uncertainty.validation:validate", "nperseg")
    with pytest.raises(PipelineError, match="'x0' is typed 'Any'"):
        library_fields("aeroid.uncertainty.validation:validate", "x0")
    with pytest.raises(PipelineError, match="not listed"):
        library_fields(
            "aeroid.uncertainty.validation:validate", "confidence", whiteness_lags=Field(None)
        )
    made = library_fields(
        "aeroid.uncertainty.validation:validate", "x0", x0=(dict[str, float] | None, Field(None))
    )
    assert made(x0={"q": 0.0}).x0 == {"q": 0.0}


def test_identify_options_take_what_the_library_takes():
    opts = STAGES["identify"].options
    assert opts.model_validate({"estimate_x0": ["alpha"]}).estimate_x0 == ["alpha"]
    assert opts.model_validate({"estimate_x0": True}).estimate_x0 is True
    for name in ("estimate_process_noise", "filter_options"):
        assert name in opts.model_fields
    # unset, the new options leave keys of results stored before them unchanged
    assert "filter_options" not in opts.model_validate({}).key_document()


def test_identify_choices_are_the_librarys():
    # the config check refuses a value identify would refuse: the two lists agree
    from typing import get_args

    from aeroid.estimation import identification

    fields = STAGES["identify"].options.model_fields
    for option, library in (("gradient", "_GRADIENTS"), ("error_bars", "_ERROR_BARS")):
        allowed = {a for m in get_args(fields[option].annotation) for a in get_args(m)}
        assert allowed == set(getattr(identification, library)), option


def test_infer_takes_parameters_and_priors_as_its_old_name_with_the_same_key(tmp_path):
    old = _config(tmp_path, "  infer: {priors: {M_q: {normal: [-2.0, 2.0]}}, n_steps: 5}\n")
    with pytest.warns(FutureWarning, match=r"stages.infer.priors is the old name of parameters"):
        before = plan(old)
    new_dir = tmp_path / "new"
    new_dir.mkdir()
    new = _config(new_dir, "  infer: {parameters: {M_q: {normal: [-2.0, 2.0]}}, n_steps: 5}\n")
    after = plan(new)
    assert [t.key for t in before.tasks] == [t.key for t in after.tasks]


def test_infer_holds_the_parameters_it_does_not_sample_at_the_fit(tmp_path):
    # a posterior of M_q alone is conditional on M_delta at its fitted value, not on the
    # model's nominal one
    cfg = _config(tmp_path, "  infer: {parameters: {M_q: {normal: [-2.0, 2.0]}}, n_steps: 4}\n")
    summary = run(cfg, workers=0)
    store = open_store(tmp_path / "store")
    tasks = {t.step: t for t in summary.plan.tasks if t.flight == summary.plan.tasks[0].flight}
    fit = store.load(tasks["identify"].key, "identify")
    post = store.load(tasks["infer"].key, "infer")
    assert post.fixed["M_delta"] == pytest.approx(fit.parameters["M_delta"], rel=1e-12)
    from aeroid.models.catalog import short_period

    assert post.fixed["M_delta"] != pytest.approx(short_period().parameters["M_delta"])


def test_stages_call_the_library_by_import_not_by_name():
    for name in ("library_stages.py", "campaign_report.py"):
        (path,) = ENGINE.rglob(name)
        text = path.read_text(encoding="utf-8")
        assert "getattr(aeroid" not in text and "import aeroid\n" not in text, path


def test_engine_modules_are_small():
    sizes = {
        str(p.relative_to(ENGINE)): len(p.read_text(encoding="utf-8").splitlines())
        for p in ENGINE.rglob("*.py")
    }
    (runner,) = [n for n in sizes if Path(n).name == "runner.py"]
    assert sizes[runner] <= 400
    assert {name: n for name, n in sizes.items() if n > 600} == {}


def test_renamed_stages_keep_their_old_names_keys_and_store_folders(tmp_path):
    import warnings

    from aeroid.pipeline.definition import Pipeline, Step
    from aeroid.pipeline.stages import STAGE_ALIASES

    renamed = {
        "frequency": "frequency_response",
        "frequency_id": "composite_response",
        "frequency_identify": "frequency_domain_identify",
    }
    assert renamed == STAGE_ALIASES
    for old, new in renamed.items():
        assert old in STAGES and old not in list(STAGES) and new in list(STAGES)
        assert STAGES[old] is STAGES[new] is STAGES.get(old)
        # results stored under the old name are found: the same key, the same folder
        assert STAGES[new].name == new and STAGES[new].key_name == old
    assert STAGES.get("frequencies") is None and "frequencies" not in STAGES
    with pytest.raises(KeyError):
        STAGES["frequencies"]
    # the built-in pipeline runs the new names; one naming an old name still loads, warned
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        p = plan(_config(tmp_path, "  frequency: {outputs: [q]}\n"))
    assert {t.stage for t in p.tasks if t.step == "frequency"} == {"frequency"}
    with pytest.warns(DeprecationWarning, match="'frequency_id', now called 'composite_response'"):
        Pipeline("mine", (Step("load"), Step("frequency_id", inputs={"data": "load"})))


def test_importing_the_engine_registers_every_built_in_stage_once():
    # a fresh interpreter, whichever engine module it imports first: the built-in stages
    # are all there, in one order, each run by the stage module that defines it
    code = (
        "import json, sys\n"
        "import aeroid.pipeline.{first}\n"
        "from aeroid.pipeline import STAGES\n"
        "print(json.dumps([[n, s.name, s.run.__module__] for n, s in STAGES.items()]))\n"
    )
    seen = []
    for first in ("stages", "store", "planning", "codec"):
        out = subprocess.run(
            [sys.executable, "-c", code.format(first=first)],
            capture_output=True,
            text=True,
            check=True,
        )
        seen.append(json.loads(out.stdout))
    assert all(s == seen[0] for s in seen)
    names = [n for n, _, _ in seen[0]]
    assert names[0] == "load" and names[-1] == "campaign_report"
    assert len(names) == len(set(names)) and {"identify", "propagate", "report"} <= set(names)
    assert all(n == name for n, name, _ in seen[0])
    homes = {"load_stage", "library_stages", "analysis_stages", "database_stage", "campaign_report"}
    assert {module.rsplit(".", 1)[1] for _, _, module in seen[0]} == homes


def test_a_task_status_is_frozen_and_reads_as_the_mapping_it_replaced():
    s = TaskStatus("k", "identify", "f1", "failed", error="boom")
    assert s["status"] == "failed" and s.get("error") == "boom" and s.get("markdown") is None
    assert s.get("warnings", ["none"]) == ["none"]
    with pytest.raises(KeyError):
        s["nothing"]
    with pytest.raises(AttributeError):
        s.status = "ok"  # type: ignore[misc]


# -- configs import nothing by surprise -------------------------------------------------------

MARKER_CODE = "from pathlib import Path\nPath({marker!r}).write_text('imported')\n"


def test_a_pipeline_in_a_parent_folder_is_not_imported(tmp_path):
    marker = tmp_path / "ran"
    (tmp_path / "pipelines").mkdir()
    (tmp_path / "pipelines" / "campaign.py").write_text(MARKER_CODE.format(marker=str(marker)))
    below = tmp_path / "project"
    below.mkdir()
    p = plan(_config(below))
    assert not marker.exists()
    assert Path(p.tasks[0].pipeline_ref["file"]) == ROOT / "pipelines" / "campaign.py"
    assert str(tmp_path) not in sys.path and str(below) not in sys.path


def test_a_pipeline_beside_the_config_is_loaded_by_path(tmp_path):
    (tmp_path / "pipelines").mkdir()
    source = (ROOT / "pipelines" / "campaign.py").read_text(encoding="utf-8")
    (tmp_path / "pipelines" / "mine.py").write_text(source.replace('"campaign"', '"mine"'))
    p = plan(_config(tmp_path, head="pipeline: mine\n"))
    assert p.pipeline.name == "mine"
    assert str(tmp_path) not in sys.path and str(tmp_path / "pipelines") not in sys.path


MODEL_CODE = "from aeroid import catalog\n\ndef build():\n    return catalog.short_period()\n"


def test_a_module_model_runs_code_and_needs_the_users_consent(tmp_path):
    (tmp_path / "vehicle.py").write_text(MODEL_CODE)
    cfg = _config(tmp_path, head="")
    cfg.write_text(cfg.read_text().replace("model: short_period", "model: vehicle:build"))
    with pytest.raises(ConfigError, match=r"model: 'vehicle:build' runs Python code .*--allow"):
        plan(cfg)
    assert plan(cfg, allow_imports=True).tasks
    metric = _config(tmp_path, "  propagate: {metric: 'os.path:getsize'}\n")
    with pytest.raises(ConfigError, match=r"stages.propagate.metric: 'os.path:getsize' runs"):
        plan(metric)


def test_the_command_line_refuses_a_module_model_unless_allowed(tmp_path):
    (tmp_path / "vehicle.py").write_text(MODEL_CODE)
    cfg = _config(tmp_path, n=1)
    cfg.write_text(cfg.read_text().replace("model: short_period", "model: vehicle:build"))
    refused = CliRunner().invoke(main, ["status", str(cfg)])
    assert refused.exit_code == 2 and "--allow-imports" in refused.output
    allowed = CliRunner().invoke(main, ["status", str(cfg), "--allow-imports"])
    assert allowed.exit_code == 0, allowed.output


@pytest.mark.slow
def test_a_dask_module_beside_the_config_does_not_replace_dask(tmp_path):
    marker = tmp_path / "ran"
    (tmp_path / "dask.py").write_text(MARKER_CODE.format(marker=str(marker)))
    (tmp_path / "vehicle.py").write_text(MODEL_CODE)
    cfg = _config(tmp_path, n=1)
    cfg.write_text(cfg.read_text().replace("model: short_period", "model: vehicle:build"))
    script = (
        "import sys\nfrom aeroid.pipeline import plan\n"
        f"plan({str(cfg)!r}, allow_imports=True)\n"
        "import dask, dask.local\nprint(dask.__file__)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, env=env
    )
    assert out.returncode == 0, out.stderr
    assert not marker.exists() and str(tmp_path) not in out.stdout


# -- reports overwrite nothing of the user's ----------------------------------------------------


def test_report_paths_that_would_overwrite_inputs_or_each_other_are_refused(tmp_path):
    cfg = _config(tmp_path)
    text = cfg.read_text()
    cfg.write_text(text.replace("report: out/report.md", "report: out/report.html"))
    with pytest.raises(ConfigError, match=r"report: report.html: name the Markdown report"):
        run(cfg, workers=0)
    cfg.write_text(text.replace("report: out/report.md", "report: c.yaml"))
    with pytest.raises(ConfigError, match=r"c.yaml is an input of the campaign"):
        run(cfg, workers=0)
    # refused before the store or the report's folder is made
    assert not (tmp_path / "store").exists() and not (tmp_path / "out").exists()
    (tmp_path / "blocker").write_text("a file where the report's folder would go\n")
    cfg.write_text(text.replace("report: out/report.md", "report: blocker/sub/report.md"))
    with pytest.raises(ConfigError, match=r"cannot make .*blocker is a file"):
        run(cfg, workers=0)
    cfg.write_text(text.replace("report: out/report.md\n", "name: ../elsewhere\n"))
    with pytest.raises(ConfigError, match=r"name: .*names the report file.*'\.\./elsewhere'"):
        run(cfg, workers=0)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "report.md").write_text("# my own notes\n")
    cfg.write_text(text)
    with pytest.raises(ConfigError, match=r"report.md exists and was not written by aeroid"):
        run(cfg, workers=0)
    assert (tmp_path / "out" / "report.md").read_text() == "# my own notes\n"
    assert not list((tmp_path / "store").glob("*/*"))  # nothing computed


def test_a_report_written_by_a_run_is_rewritten_by_the_next(tmp_path):
    cfg = _config(tmp_path, n=1)
    first = run(cfg, workers=0)
    assert first.report_path is not None and first.failed == 0
    cfg.write_text(cfg.read_text().replace("  validate: {}", "  validate: {confidence: 0.9}"))
    again = run(cfg, workers=0)
    assert again.report_path == first.report_path and again.count("computed") > 0


def test_a_full_disk_names_the_report_and_still_prints_the_table(tmp_path, monkeypatch):
    from aeroid.reports import html as _html

    def full(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(_html, "_atomic_write", full)
    cfg = _config(tmp_path, n=1)
    result = CliRunner().invoke(main, ["run", str(cfg), "--workers", "0", "--json"])
    assert result.exit_code == 1
    doc = json.loads(result.stdout)
    assert doc["failed"] == 0 and doc["report"] is None
    assert "report.md" in doc["report_error"] and "No space left" in doc["report_error"]
    table = CliRunner().invoke(main, ["run", str(cfg), "--workers", "0"])
    assert table.exit_code == 1 and "| flight" in table.stdout
    assert "error: cannot write the report" in table.stderr and "report.md" in table.stderr


# -- rerun --all on the executors of a run ------------------------------------------------------


@pytest.mark.slow
def test_rerun_all_on_worker_processes_finds_every_entry_bit_identical(tmp_path):
    cfg = _config(tmp_path, "  propagate: {n_samples: 200, n_batches: 2}\n")
    assert run(cfg, workers=0).failed == 0
    store = open_store(tmp_path / "store")
    n = sum(1 for _ in store.entries())
    seen: list[str] = []
    local = rerun_all(store, executor=LocalProcesses(2), on_done=lambda r: seen.append(r.entry.key))
    assert len(local) == len(seen) == n
    assert all(r.identical and not r.failed for r in local), [r.lines for r in local]
    one = rerun_all(store, stage="identify", executor=InProcess())
    assert len(one) == 2 and all(r.identical for r in one)


def test_a_report_only_rerun_draws_its_figure_parts_on_every_worker(tmp_path):
    from aeroid.pipeline.running.executors import pool_size
    from aeroid.pipeline.running.runner import n_parts

    cfg = _config(tmp_path, n=3)
    cfg.write_text(cfg.read_text().replace("figures: false", "figures: true"))
    p = plan(cfg)
    report = p.report_task
    assert report is not None and n_parts(report) > 2  # the figures split into parts
    # the report alone (every flight cached) still gets every worker
    assert pool_size([report], 4) == 4
    # one flight's chain of whole tasks: no more workers than tasks
    load = next(t for t in p.tasks if t.step == "load")
    assert pool_size([load], 4) == 1
    assert pool_size(p.tasks, 2) == 2


@pytest.mark.skipif(sys.platform != "linux", reason="workers are forked on Linux only")
def test_a_forking_run_imports_its_stages_libraries_before_the_workers_fork(tmp_path):
    # the run's own process computes nothing, so it imports the libraries only to share
    # their pages with the forked workers
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "name: c\nmodel: short_period\npipeline: campaign\nseed: 1\nstore: store\n"
        "report: out/c.md\nflights:\n  - simulated: {generator: short_period_campaign, "
        "n_flights: 3, seed: 3, maneuver: doublet, duration: 4.0, sample_rate: 20.0}\n"
        "stages:\n  identify: {parameters: [M_alpha, M_q]}\n  validate: {}\n"
        "  campaign_report: {figures: false, include_flight_reports: false}\n",
        encoding="utf-8",
    )
    code = (
        "import sys\n"
        "from aeroid.pipeline import _process, run\n"
        "if {off}:\n"
        "    _process.share_imports = lambda libraries, **kw: None\n"
        f"run({str(cfg)!r}, workers=2)\n"
        "print(sorted(m for m in ('aeroid.estimation.identification', 'aeroid.uncertainty.validation', "
        "'scipy.optimize', 'jax', 'scipy.stats') if m in sys.modules))\n"
    )
    seen = {}
    for off in (True, False):
        out = subprocess.run(
            [sys.executable, "-c", code.format(off=off)],
            capture_output=True,
            text=True,
            check=True,
            cwd=tmp_path,
        )
        seen[off] = out.stdout.strip().splitlines()[-1]
        (tmp_path / "store").rename(tmp_path / f"store_{off}")
    assert seen[True] == "[]"  # without it, the workers import them, each on its own
    # JAX too, as the run fits models (imported, not started: the workers still fork);
    # not scipy.stats, which no task of the run imports
    jax = ["jax"] if importlib.util.find_spec("jax") is not None else []
    assert seen[False] == str(
        sorted(
            [
                "aeroid.estimation.identification",
                "aeroid.uncertainty.validation",
                "scipy.optimize",
                *jax,
            ]
        )
    )


def test_a_model_module_edited_in_one_process_is_resolved_again(tmp_path):
    # its source is in the task keys: the model that runs must be the edited one,
    # or a fit of the old model would be stored under the new model's keys
    from aeroid.pipeline.vehicle import resolve_model

    (tmp_path / "vehicle.py").write_text(MODEL_CODE)
    first = resolve_model("vehicle:build", str(tmp_path))
    assert resolve_model("vehicle:build", str(tmp_path)) is first  # unchanged: once
    edited = MODEL_CODE.replace(
        "short_period()", "short_period({**catalog.SHORT_PERIOD_TRUTH, 'M_q': -7.25})"
    )
    (tmp_path / "vehicle.py").write_text(edited)
    again = resolve_model("vehicle:build", str(tmp_path))
    assert again is not first and again.parameters["M_q"] == -7.25


def test_a_renamed_flight_file_reuses_its_results_under_its_new_name(tmp_path):
    # the data are keyed by their bytes, so the fits are reused; what shows the flight's
    # name and file (its report) is made again and equals a fresh campaign's
    from aeroid.models import catalog

    def campaign(folder: Path, names: list[str]) -> Path:
        folder.mkdir(exist_ok=True)
        for seed, name in enumerate(names):
            if not (folder / name).exists():
                catalog.short_period_flight(seed=seed, duration=4.0).to_csv(folder / name)
        cfg = folder / "c.yaml"
        cfg.write_text(
            "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
            f"flights: {names}\n"
            "stages:\n  identify: {parameters: [M_q, M_delta]}\n  validate: {}\n"
            "  report: {}\n  campaign_report: {figures: false}\n"
        )
        return cfg

    cfg = campaign(tmp_path / "a", ["f1.csv", "f2.csv"])
    first = run(cfg, workers=0)
    (tmp_path / "a" / "f2.csv").rename(tmp_path / "a" / "sortie_b.csv")
    again = run(campaign(tmp_path / "a", ["f1.csv", "sortie_b.csv"]), workers=0)
    assert again.failed == 0 and again.count("computed") < first.count("computed")
    text = again.report_path.read_text()
    assert "f2" not in text and "Flight sortie_b" in text and "sortie_b.csv" in text
    fresh = tmp_path / "b"
    fresh.mkdir()
    for name in ("f1.csv", "sortie_b.csv"):
        (fresh / name).write_bytes((tmp_path / "a" / name).read_bytes())
    alone = run(campaign(fresh, ["f1.csv", "sortie_b.csv"]), workers=0)
    assert alone.report_path.read_text() == text
