"""The user's code a campaign runs keys its tasks: the whole file a ``module:attribute``
model or metric names, the user's modules it imports from the config's folder, and a
pipeline file's own stages; an edit recomputes exactly what runs it, nothing else."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from aeroid.pipeline import open_store, plan, run
from aeroid.pipeline.keys import model_fingerprint

ROOT = Path(__file__).resolve().parents[1]

# the dynamics call a helper that reads a module-level constant: neither is in the
# dynamics function's own text
MODEL = """\
import numpy as np
import aeroid
{imports}
SCALE = {scale}


def helper(u):
    return {helper}


def _dyn(t, x, u, p):
    alpha, q = x[0], x[1]
    return np.array([p["Z_alpha"] * alpha + q,
                     p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * helper(u[0])])


model = aeroid.Model(states=["alpha", "q"], controls=["elevator"],
                     parameters={{"Z_alpha": -0.8, "M_alpha": -4.0, "M_q": -1.5, "M_delta": -6.0}},
                     dynamics=_dyn, name="mine")
"""

METRIC = """\
import math


def wn(p):
    return {factor} * math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"])
"""

# every step that runs the model, or reads what it fitted; the flights' loads do not
MODEL_STEPS = ["campaign_report", "identify", "propagate", "report", "validate"]


def _campaign(root: Path, *, model: str = "short_period", metric: str = "natural_frequency"):
    root.mkdir(parents=True, exist_ok=True)
    cfg = root / "c.yaml"
    cfg.write_text(
        f"model: {model!r}\nallow_imports: true\nseed: 5\nstore: store\n"
        "report: out/report.md\n"
        "flights: [{simulated: {n_flights: 2, seed: 1, duration: 4.0}}]\n"
        "stages:\n  identify: {parameters: [M_delta]}\n  validate: {}\n"
        f"  propagate: {{metric: {metric!r}, n_samples: 50}}\n"
        "  campaign_report: {figures: false}\n"
    )
    return cfg


def _model(root: Path, *, scale: str = "1.0", helper: str = "SCALE * u", imports: str = ""):
    (root / "mymodel.py").write_text(MODEL.format(scale=scale, helper=helper, imports=imports))


def _keys(cfg: Path) -> dict[tuple[str, str | None], str]:
    return {(t.step, t.flight): t.key for t in plan(cfg).tasks}


def _changed(before: dict, after: dict) -> list[str]:
    """The steps some of whose tasks' keys changed."""
    assert before.keys() == after.keys()
    return sorted({step for (step, _), key in after.items() if before[step, _] != key})


def _m_delta(cfg: Path) -> list[float]:
    store = open_store(cfg.parent / "store")
    return sorted(store.load(e.key).parameters["M_delta"] for e in store.entries("identify"))


def _computed(summary) -> list[str]:
    return sorted({r["stage"] for r in summary.task_rows() if r["status"] == "computed"})


def test_a_model_helpers_constant_edited_recomputes_the_fits(tmp_path):
    # the finding: SCALE 1.0 -> 0.5 served the old fit as cached (computed 0), its
    # M_delta half the edited model's. The effective gain halves: M_delta doubles.
    cfg = _campaign(tmp_path, model="mymodel:model")
    _model(tmp_path, scale="1.0")
    first = run(cfg, workers=0)
    assert first.failed == 0
    before = _m_delta(cfg)
    _model(tmp_path, scale="0.5")
    again = run(cfg, workers=0)
    assert _computed(again) == MODEL_STEPS and again.count("cached") == 2  # the loads
    fits = _m_delta(cfg)
    new = [m for m in fits if m not in before]
    assert len(new) == 2
    # the same least-squares problem in M_delta * 0.5: its optimum, to the fit's tolerance
    # (the old fit, served before, is off by a factor 2)
    assert sorted(new) == pytest.approx([2 * m for m in before], rel=1e-4)
    assert run(cfg, workers=0).count("computed") == 0  # unchanged: nothing


def test_a_model_helpers_body_edited_changes_the_keys_of_what_runs_the_model(tmp_path):
    cfg = _campaign(tmp_path, model="mymodel:model")
    _model(tmp_path)
    before = _keys(cfg)
    assert _keys(cfg) == before
    _model(tmp_path, helper="0.5 * SCALE * u")
    assert _changed(before, _keys(cfg)) == MODEL_STEPS
    # a comment is text too: the file is keyed whole, not parsed for meaning
    (tmp_path / "mymodel.py").write_text((tmp_path / "mymodel.py").read_text() + "# note\n")
    assert _changed(before, _keys(cfg)) == MODEL_STEPS


def test_an_imported_local_module_edited_recomputes_with_the_edited_module(tmp_path, monkeypatch):
    # `import aero_kc1`: found from the import statement in the config's
    # folder; the session then imports the edited module, not the one it holds
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "aero_kc1", raising=False)
    cfg = _campaign(tmp_path, model="mymodel:model")
    _model(tmp_path, scale="aero_kc1.SCALE", imports="import aero_kc1")
    (tmp_path / "aero_kc1.py").write_text("SCALE = 1.0\n")
    run(cfg, workers=0)
    before_keys, before = _keys(cfg), _m_delta(cfg)
    (tmp_path / "aero_kc1.py").write_text("SCALE = 0.5\n")
    assert _changed(before_keys, _keys(cfg)) == MODEL_STEPS
    again = run(cfg, workers=0)
    assert _computed(again) == MODEL_STEPS
    new = [m for m in _m_delta(cfg) if m not in before]
    assert sorted(new) == pytest.approx([2 * m for m in before], rel=1e-4)
    assert run(cfg, workers=0).count("computed") == 0
    monkeypatch.delitem(sys.modules, "aero_kc1", raising=False)


def test_a_local_packages_relative_imports_are_followed(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("vehicle_kc2", "vehicle_kc2.aero", "vehicle_kc2.tables"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    pkg = tmp_path / "vehicle_kc2"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("from .aero import SCALE\n")
    (pkg / "aero.py").write_text("from . import tables\nSCALE = tables.GAIN\n")
    (pkg / "tables.py").write_text("GAIN = 1.0\n")
    (pkg / "unused.py").write_text("X = 1\n")
    cfg = _campaign(tmp_path, model="mymodel:model")
    _model(tmp_path, scale="vehicle_kc2.SCALE", imports="import vehicle_kc2")
    before = _keys(cfg)
    (pkg / "unused.py").write_text("X = 2\n")  # imported by nothing: keys nothing
    assert _keys(cfg) == before
    (pkg / "tables.py").write_text("GAIN = 0.5\n")
    assert _changed(before, _keys(cfg)) == MODEL_STEPS
    code = plan(cfg).tasks[1].document["model"]["code"]
    assert sorted(code) == ["mymodel", "vehicle_kc2", "vehicle_kc2.aero", "vehicle_kc2.tables"]


def test_aeroid_and_installed_modules_are_not_keyed_by_file(tmp_path):
    # they are keyed by the stages' versions: a config in a folder that holds aeroid's
    # own source (a checkout) keys none of it, nor numpy, which is not in the folder
    from aeroid.pipeline import _code

    assert _code.user_code("aeroid.pipeline.keys", ROOT) == {}
    cfg = _campaign(tmp_path, model="mymodel:model")
    _model(tmp_path)
    (tmp_path / "numpy").mkdir()  # no module file: not keyed either
    assert list(plan(cfg).tasks[1].document["model"]["code"]) == ["mymodel"]


def test_keys_hold_the_text_not_its_line_endings_or_its_path(tmp_path):
    a, b = tmp_path / "a", tmp_path / "elsewhere" / "b"
    for root in (a, b):
        _campaign(root, model="mymodel:model")
        _model(root)
    text = (b / "mymodel.py").read_text()
    (b / "mymodel.py").write_bytes(text.replace("\n", "\r\n").encode())
    assert _keys(a / "c.yaml") == _keys(b / "c.yaml")


def test_a_built_in_model_and_metric_keep_their_keys(tmp_path):
    # no user code: no ``code`` in any key, the fingerprint as before
    cfg = _campaign(tmp_path)
    for task in plan(cfg).tasks:
        assert "code" not in task.document
        model = task.document["model"]
        assert model is None or "code" not in model
    from aeroid.models.catalog import short_period

    assert plan(cfg).tasks[1].document["model"] == model_fingerprint(short_period())


def test_a_metrics_body_edited_changes_the_keys_of_the_propagation_only(tmp_path):
    cfg = _campaign(tmp_path, metric="mymetric_kc3:wn")
    (tmp_path / "mymetric_kc3.py").write_text(METRIC.format(factor="1.0"))
    before = _keys(cfg)
    (tmp_path / "mymetric_kc3.py").write_text(METRIC.format(factor="2.0"))
    # the reports show the propagation: they are made again, nothing else
    assert _changed(before, _keys(cfg)) == ["campaign_report", "propagate", "report"]
    propagate = next(t for t in plan(cfg).tasks if t.step == "propagate")
    assert list(propagate.document["code"]) == ["options.metric"]


def _cli(cfg: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(cfg.parent)]))
    return subprocess.run(
        [sys.executable, "-c", "from aeroid.cli import main; main()", "run", str(cfg), *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=cfg.parent,
    )


def test_a_metrics_body_edited_recomputes_its_monte_carlo(tmp_path):
    # the finding: the metric doubled, the run served the old mean (computed 0)
    import json

    cfg = _campaign(tmp_path, metric="mymetric_kc4:wn")
    (tmp_path / "mymetric_kc4.py").write_text(METRIC.format(factor="1.0"))
    assert _cli(cfg, "--workers", "0").returncode == 0
    store = open_store(tmp_path / "store")
    before = {e.key: store.load(e.key).mean for e in store.entries("propagate")}
    (tmp_path / "mymetric_kc4.py").write_text(METRIC.format(factor="2.0"))
    out = _cli(cfg, "--workers", "0", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    # the flights' propagations and reports, and the campaign's report
    assert doc["computed"] == 5 and doc["cached"] == 6
    store = open_store(tmp_path / "store")
    after = {e.key: store.load(e.key).mean for e in store.entries("propagate")}
    new = sorted(v for k, v in after.items() if k not in before)
    # the same seeded draws through twice the function: exactly twice the mean
    assert new == pytest.approx(sorted(2 * v for v in before.values()), rel=1e-12)
    assert json.loads(_cli(cfg, "--workers", "0", "--json").stdout)["computed"] == 0


@pytest.mark.parametrize("n_batches", [None, 2])
def test_a_metric_beside_the_config_runs_where_its_check_found_it(tmp_path, n_batches):
    # the finding: the check found mymetric.py beside the config, then every propagate
    # failed to import it (the worker looked among the installed modules only)
    from aeroid.pipeline.running.rerun import rerun

    name = f"mymetric_kc5_{n_batches}"
    cfg = _campaign(tmp_path, metric=f"{name}:wn")
    if n_batches:
        cfg.write_text(cfg.read_text().replace("n_samples: 50", "n_samples: 50, n_batches: 2"))
    (tmp_path / f"{name}.py").write_text(METRIC.format(factor="2.0"))
    assert str(tmp_path) not in sys.path
    summary = run(cfg, workers=0)
    assert summary.failed == 0
    plain = _campaign(tmp_path / "plain")
    if n_batches:
        plain.write_text(plain.read_text().replace("n_samples: 50", "n_samples: 50, n_batches: 2"))
    assert run(plain, workers=0).failed == 0
    store, other = open_store(tmp_path / "store"), open_store(tmp_path / "plain" / "store")

    def samples(s):
        return sorted(tuple(s.load(e.key).samples) for e in s.entries("propagate"))

    # the same seeded draws through twice the built-in natural frequency
    got, want = samples(store), samples(other)
    assert len(got) == 2
    for g, w in zip(got, want, strict=True):
        assert np.asarray(g) == pytest.approx(2.0 * np.asarray(w), rel=1e-12)
    for entry in store.entries("propagate"):  # a rerun from the stored task finds the file
        assert rerun(store, entry.key)[0]


def test_a_model_file_imports_its_folders_modules_under_the_command(tmp_path):
    # the finding: `from helper import GAIN` beside the config worked only from a cwd
    # Python had put on sys.path; a package's relative import never did
    (tmp_path / "helper_kc6.py").write_text("SCALE = 0.5\n")
    (tmp_path / "mymodel.py").write_text(
        MODEL.format(scale="1.0", helper="SCALE * u", imports="")
        .replace("SCALE = 1.0\n", "")
        .replace(
            "import aeroid\n", "import aeroid\nimport colorsys\nfrom helper_kc6 import SCALE\n"
        )
    )
    # a file beside the config named as an installed module shadows nothing
    (tmp_path / "colorsys.py").write_text("raise RuntimeError('shadowed the stdlib')\n")
    package = tmp_path / "mypkg_kc6"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "helper.py").write_text("SCALE = 0.5\n")
    (package / "mymodel.py").write_text(
        (tmp_path / "mymodel.py")
        .read_text()
        .replace("from helper_kc6 import SCALE", "from .helper import SCALE")
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    fits = []
    for name, spec in (("a", "mymodel:model"), ("b", "mypkg_kc6.mymodel:model")):
        cfg = _campaign(tmp_path / name, model=spec)
        cfg = cfg.rename(tmp_path / f"{name}.yaml")
        cfg.write_text(cfg.read_text().replace("store: store", f"store: store_{name}"))
        out = subprocess.run(
            [sys.executable, "-c", "from aeroid.cli import main; main()", "run", str(cfg)],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
            cwd="/",
        )
        assert out.returncode == 0, out.stderr
        store = open_store(tmp_path / f"store_{name}")
        fits.append(
            sorted(store.load(e.key).parameters["M_delta"] for e in store.entries("identify"))
        )
    # the same fits either way: the helper's gain of 0.5, M_delta twice the truth's
    assert fits[0] == pytest.approx(fits[1], rel=1e-12)


STAGE_PIPELINE = textwrap.dedent(
    """
    from dataclasses import dataclass

    import numpy as np

    from aeroid.pipeline import Pipeline, Stage, Step, register_record, register_stage
    from aeroid.pipeline.plans.config import Options

    SHIFT = {shift}


    @register_record
    @dataclass(frozen=True, eq=False)
    class Shifted:
        mean: np.ndarray

        def summary(self):
            return "shifted"


    class ShiftOptions(Options):
        pass


    def run_shift(ctx):
        data = ctx.inputs["data"]
        return Shifted(data.array(list(data.names)).mean(axis=0) + SHIFT)


    register_stage(Stage("shift_kc5", "1", ShiftOptions, "pipe_kc5:Shifted", run_shift,
                         uses_model=False))

    pipeline = Pipeline(
        "user",
        flight_steps=(Step("load"), Step("shift_kc5", inputs={{"data": "load"}})),
        campaign_steps=(Step("campaign_report", inputs={{"data": "load"}}),),
    )
    """
)


def test_a_pipeline_files_own_stage_is_keyed_by_that_file(tmp_path):
    (tmp_path / "pipe_kc5.py").write_text(STAGE_PIPELINE.format(shift="1.0"))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\npipeline: 'pipe_kc5:pipeline'\nstore: store\n"
        "flights: [{simulated: {n_flights: 2, seed: 1, duration: 4.0}}]\n"
        "stages:\n  campaign_report: {figures: false}\n"
    )
    before = _keys(cfg)
    shift = next(t for t in plan(cfg).tasks if t.step == "shift_kc5")
    assert list(shift.document["code"]["stage"]) == ["pipe_kc5"]
    (tmp_path / "pipe_kc5.py").write_text(STAGE_PIPELINE.format(shift="2.0"))
    # the built-in steps run none of the file's code: their keys stay
    assert _changed(before, _keys(cfg)) == ["shift_kc5"]
