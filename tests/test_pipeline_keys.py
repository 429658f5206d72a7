"""Content keys: canonical JSON, array digests, model fingerprints, load keys from bytes."""

from __future__ import annotations

import hashlib
import json
import math
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aeroid.errors import PipelineError
from aeroid.models.catalog import short_period, short_period_flight
from aeroid.models.model import Model
from aeroid.pipeline import plan
from aeroid.pipeline.keys import (
    array_digest,
    canonical_json,
    model_fingerprint,
    sha256_hex,
    stable_int,
    task_key,
)

MINI = textwrap.dedent(
    """
    from aeroid.pipeline import Pipeline, Step
    pipeline = Pipeline("mini", flight_steps=(Step("load"),),
                        campaign_steps=(Step("campaign_report", inputs={"data": "load"}),))
    """
)


def test_canonical_json_is_order_free_and_compact():
    a = canonical_json({"b": 1, "a": (1.5, None, True), "c": {"y": 2, "x": "é"}})
    b = canonical_json({"c": {"x": "é", "y": 2}, "a": [1.5, None, True], "b": 1})
    assert a == b
    assert a == '{"a":[1.5,null,true],"b":1,"c":{"x":"é","y":2}}'.encode()


def test_canonical_json_spells_out_non_finite_and_numpy_scalars():
    doc = canonical_json({"n": math.nan, "i": np.inf, "k": np.int64(3), "f": np.float32(0.5)})
    assert doc == b'{"f":0.5,"i":{"__float__":"inf"},"k":3,"n":{"__float__":"nan"}}'


def test_canonical_json_refuses_what_it_cannot_hash_deterministically():
    with pytest.raises(PipelineError, match=r"options\.f"):
        canonical_json({"options": {"f": object()}})


def test_array_digest_covers_dtype_shape_and_bytes():
    x = np.arange(6.0)
    assert array_digest(x) == array_digest(x.copy())
    assert array_digest(x) != array_digest(x.reshape(2, 3))
    assert array_digest(x) != array_digest(x.astype(np.float32))
    y = x.copy()
    y[3] = np.nextafter(y[3], 10)
    assert array_digest(x) != array_digest(y)
    assert array_digest(x[::2]) == array_digest(np.ascontiguousarray(x[::2]))


def _key(**changes):
    base = dict(
        record_type="r",
        stage="identify",
        stage_version="1",
        options={"a": 1, "b": [1, 2]},
        upstream={"data": "k1"},
        model={"name": "m"},
        seed={"seed": 0, "spawn_key": [1]},
    )
    base.update(changes)
    return task_key(**base)[0]


def test_task_key_depends_on_every_component():
    k = _key()
    assert k == _key(options={"b": [1, 2], "a": 1})  # order does not matter
    variants = [
        _key(record_type="s"),
        _key(stage="validate"),
        _key(stage_version="2"),
        _key(options={"a": 2, "b": [1, 2]}),
        _key(upstream={"data": "k2"}),
        _key(model={"name": "n"}),
        _key(seed={"seed": 1, "spawn_key": [1]}),
        _key(seed=None),
        _key(model=None),
    ]
    assert len({k, *variants}) == len(variants) + 1
    assert len(k) == 64 and int(k, 16) >= 0


def test_model_fingerprint_tracks_values_source_and_version():
    a, b = short_period(), short_period()
    assert model_fingerprint(a) == model_fingerprint(b)
    assert model_fingerprint(a) != model_fingerprint(
        short_period({"Z_alpha": -1.0, "M_alpha": -4, "M_q": -1.5, "M_delta": -6})
    )
    tagged = Model(a.states, a.controls, dict(a.parameters), a.dynamics, name=a.name, version="2")
    assert model_fingerprint(tagged) != model_fingerprint(a)

    def other(t, x, u, p):  # same structure, different dynamics source
        return np.array([p["Z_alpha"] * x[0], p["M_q"] * x[1] + p["M_alpha"] + p["M_delta"] * u[0]])

    changed = Model(a.states, a.controls, dict(a.parameters), other, name=a.name)
    fp = model_fingerprint(changed)
    assert fp != model_fingerprint(a) and 'p["M_q"] * x[1]' in fp["source"]


def test_stable_int_is_a_deterministic_63_bit_integer():
    assert stable_int("ff" * 32) == (1 << 63) - 1
    assert stable_int("0123456789abcdef" + "0" * 48) == 0x0123456789ABCDEF


def _write_flight(path: Path, seed: int) -> None:
    d = short_period_flight(seed=seed)
    cols = ["time", *d.names]
    rows = np.column_stack([d.time, *(d[n] for n in d.names)])
    path.write_text(",".join(cols) + "\n" + "\n".join(",".join(repr(v) for v in r) for r in rows))


def _config(tmp: Path, flights: str, extra: str = "") -> Path:
    (tmp / "mini_keys.py").write_text(MINI)
    cfg = tmp / "c.yaml"
    cfg.write_text(
        f"model: short_period\npipeline: mini_keys:pipeline\nflights: {flights}\n{extra}"
    )
    return cfg


def test_load_key_hashes_bytes_not_path_or_mtime(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    _write_flight(a / "f1.csv", 1)
    (b / "renamed.csv").write_bytes((a / "f1.csv").read_bytes())
    k1 = plan(_config(a, "[f1.csv]")).tasks[0].key
    k2 = plan(_config(b, "[renamed.csv]")).tasks[0].key
    assert k1 == k2
    # loader options enter the key; paths, store, workers and scheduler do not
    k3 = plan(_config(b, "[{path: renamed.csv, time_column: time}]")).tasks[0].key
    assert k3 != k1
    k4 = plan(_config(b, "[renamed.csv]", "store: elsewhere\nworkers: 3\n")).tasks[0].key
    assert k4 == k1
    _write_flight(b / "renamed.csv", 2)
    assert plan(_config(b, "[renamed.csv]")).tasks[0].key != k1


def test_adding_a_flight_leaves_other_keys_alone(tmp_path):
    for i in range(3):
        _write_flight(tmp_path / f"f{i}.csv", i)
    keys2 = {t.flight: t.key for t in plan(_config(tmp_path, "['f[01].csv']")).tasks if t.flight}
    keys3 = {t.flight: t.key for t in plan(_config(tmp_path, "['f*.csv']")).tasks if t.flight}
    assert keys3["f0"] == keys2["f0"] and keys3["f1"] == keys2["f1"]
    reports = [t.key for t in plan(_config(tmp_path, "['f*.csv']")).tasks if t.flight is None]
    assert reports[0] not in {t.key for t in plan(_config(tmp_path, "['f[01].csv']")).tasks}


def test_simulated_flight_keys_do_not_depend_on_campaign_size(tmp_path):
    def keys(n):
        p = plan(_config(tmp_path, f"[{{simulated: {{n_flights: {n}, airspeed: [60, 60]}}}}]"))
        return [t.key for t in p.tasks if t.flight]

    assert keys(3)[:2] == keys(2)


def test_task_key_is_the_sha256_of_the_documented_canonical_json():
    # Keys are what make last year's store reusable: this pins the derivation to its
    # definition (SHA-256 of sorted, compact JSON) and to a literal value, so any
    # change to it shows up here instead of as a silent recompute of every campaign.
    doc = {
        "model": {"name": "m"},
        "options": {"a": 1, "b": [1, 2]},
        "record_type": "r",
        "seed": {"seed": 0, "spawn_key": [1]},
        "stage": "identify",
        "stage_version": "1",
        "upstream": {"data": "k1"},
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    assert _key() == hashlib.sha256(text.encode("utf-8")).hexdigest()
    assert _key() == "b63e75456bdc33c165987d225bd37ff4dec392a2920c8f689cccf2b26b53aeaf"


def test_a_plans_memo_gives_the_same_keys_and_documents():
    # `plan` passes one memo for all its tasks: the options and the model are then
    # serialised once; the key stays the canonical JSON of the whole document
    model = {"name": "mødel", "parameters": {"a": float("nan"), "b": 2.5}, "src": 'x = "\u2028"'}
    options = {"z": [1, {"y": None}], "a": np.float64(-0.0), "é": True}
    memo: dict[int, tuple[object, bytes]] = {}
    odd = {'q"uote': "back\\slash\n\u2028\x01", "data": "k3"}  # escapes as json.dumps writes them
    for upstream in ({"data": "k1"}, {"data": "k2", "b": "é"}, odd):
        fields = dict(
            record_type="r",
            stage="s",
            stage_version="2",
            options=options,
            upstream=upstream,
            model=model,
            seed={"seed": 0, "spawn_key": [3]},
        )
        plain = task_key(**fields)
        memoised = task_key(**fields, memo=memo)
        assert memoised == plain
        assert memoised[1]["model"] is not plain[1]["model"]  # each document its own
        assert plain[0] == sha256_hex(canonical_json(plain[1]))
    assert len(memo) == 2
    with pytest.raises(PipelineError, match=r"s task\.options\.bad: cannot hash"):
        task_key(**{**fields, "options": {"bad": object()}}, memo=memo)


def test_an_option_added_later_enters_keys_only_once_set(tmp_path):
    # `infer: {move: ...}` came after infer keys were first stored: unset, it is left out
    # of the key document, so the keys of campaigns that do not use it stay the same
    from aeroid.pipeline.stages.library_stages import InferOptions

    priors = {"M_q": {"normal": [-2.0, 2.0]}}
    doc = InferOptions(priors=priors).key_document()
    assert "move" not in doc and doc["stretch"] is None  # options from the start stay in
    assert InferOptions(priors=priors, move="de").key_document() == {**doc, "move": "de"}

    def keys(infer: str) -> dict[tuple[str, str | None], str]:
        cfg = tmp_path / "c.yaml"
        cfg.write_text(
            "model: short_period\nflights: [{simulated: {n_flights: 1}}]\n"
            "stages:\n  identify: {parameters: [M_q]}\n"
            f"  infer: {{priors: {{M_q: {{normal: [-2.0, 2.0]}}}}{infer}}}\n"
        )
        return {(t.step, t.flight): t.key for t in plan(cfg).tasks}

    unset, stretch, de = keys(""), keys(", move: stretch"), keys(", move: de")
    changed = {k for k in unset if unset[k] != de[k]}
    assert {step for step, _ in changed} == {"infer", "report", "campaign_report"}  # downstream
    assert ("infer", "sim-0") in changed and unset[("identify", "sim-0")] == de[
        ("identify", "sim-0")
    ]
    assert stretch[("infer", "sim-0")] not in (unset[("infer", "sim-0")], de[("infer", "sim-0")])


def test_an_execution_only_option_travels_with_the_task_but_not_in_its_key(tmp_path):
    # `propagate: {n_batches: k}` changes how the draws are split over tasks, not the
    # result: keys are those without it, and each task still runs with it
    from aeroid.pipeline.running.runner import n_parts
    from aeroid.pipeline.stages.library_stages import PropagateOptions

    assert "n_batches" not in PropagateOptions(n_batches=3).key_document()
    assert PropagateOptions(n_batches=3).task_document()["n_batches"] == 3
    assert "n_batches" not in PropagateOptions().task_document()

    def tasks(propagate: str) -> dict[str, Any]:
        cfg = tmp_path / "c.yaml"
        cfg.write_text(
            "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n"
            "stages:\n  identify: {parameters: [M_q]}\n"
            f"  propagate: {{n_samples: 10{propagate}}}\n"
        )
        return {f"{t.step} {t.flight}": t for t in plan(cfg).tasks}

    plain, split, many = tasks(""), tasks(", n_batches: 4"), tasks(", n_batches: 40")
    assert {k: t.key for k, t in plain.items()} == {k: t.key for k, t in split.items()}
    assert {k: t.document for k, t in plain.items()} == {k: t.document for k, t in split.items()}
    assert split["propagate sim-0"].options["n_batches"] == 4
    assert "n_batches" not in plain["propagate sim-0"].options
    assert n_parts(plain["propagate sim-0"]) == 1 and n_parts(split["propagate sim-0"]) == 4
    assert n_parts(many["propagate sim-1"]) == 10  # never more batches than draws


def test_a_declared_integration_path_is_part_of_the_model_fingerprint():
    from aeroid import Model
    from aeroid.pipeline.keys import model_fingerprint

    def decay(t, x, u, p):
        return -p["k"] * x

    plain = model_fingerprint(Model(["x"], [], {"k": 1.0}, decay))
    assert "linear" not in plain  # keys of models that declare nothing are unchanged
    integrated = model_fingerprint(Model(["x"], [], {"k": 1.0}, decay, linear=False))
    exact = model_fingerprint(Model(["x"], [], {"k": 1.0}, decay, linear=True))
    assert integrated["linear"] is False and exact["linear"] is True
    assert len({json.dumps(fp, sort_keys=True) for fp in (plain, integrated, exact)}) == 3


def test_validate_and_infer_take_simulate_options_added_later():
    # the fit's controls between samples (`control_interpolation`) for the stages that
    # simulate it again: unset, the keys stored before stay; unknown keys are refused
    from pydantic import ValidationError

    from aeroid.pipeline.stages.library_stages import InferOptions, ValidateOptions

    cubic = {"control_interpolation": {"delta_a": "cubic"}}
    assert "simulate_options" not in ValidateOptions().key_document()
    assert ValidateOptions(simulate_options=cubic).key_document() == {
        **ValidateOptions().key_document(),
        "simulate_options": cubic,
    }
    priors = {"M_q": {"normal": [-2.0, 2.0]}}
    assert "simulate_options" not in InferOptions(priors=priors).key_document()
    got = InferOptions(priors=priors, simulate_options=cubic).library_kwargs(exclude=())
    assert got["simulate_options"] == cubic
    with pytest.raises(ValidationError, match=r"unknown keys \['spline'\]"):
        ValidateOptions(simulate_options={"spline": True})
    with pytest.raises(ValidationError, match=r"unknown keys \['spline'\]"):
        InferOptions(priors=priors, simulate_options={"spline": True})
