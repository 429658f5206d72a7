"""The stages of the analyses around the fit (compatibility, regress, frequency_id,
transfer_function, frequency_identify, handling_qualities) and loading through the channel
map: each runs in a campaign, stores its record and reads it back as the library computes it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from _compat_flight import BIASES, simulated_flight

import aeroid
from aeroid.pipeline import STAGES, open_store, plan, run
from aeroid.pipeline.stages import StageContext
from aeroid.pipeline.stages.analysis_stages import HandlingQualities
from aeroid.pipeline.storage.codec import decode, encode

ROOT = Path(__file__).resolve().parents[1]

SIMULATED = (
    "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
    "flights: [{simulated: {n_flights: 1, seed: 1, duration: 20.0, maneuver: doublet_sweep}}]\n"
    "stages:\n  identify: {parameters: [M_q, M_delta]}\n  validate: {}\n"
    "  campaign_report: {figures: false}\n"
)
NEW = (
    "  regress: {response: q, candidates: [alpha, elevator, 'alpha*q']}\n"
    "  frequency_id: {inputs: [elevator], outputs: [q, alpha], frequency_range: [1.0, 30.0],"
    " windows: [10.0, 5.0]}\n"
    "  transfer_function: {numerator_order: 1, denominator_order: 2, input: elevator,"
    " output: q}\n"
    "  frequency_identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta],"
    " frequencies: [1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.0]}\n"
    # the simulated elevator pitches the nose down (M_delta < 0): q/elevator starts at
    # -180 deg, so the bandwidth's -135 deg crossing is not defined; the LOES fit is
    "  handling_qualities: {bandwidth: false, input: elevator, output: q,"
    " equivalent_system: {kind: short_period}}\n"
)


def _records(tmp_path: Path, text: str) -> tuple[dict[str, object], object]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    summary = run(cfg, workers=0)
    failed = {k: s.get("error") for k, s in summary.statuses.items() if s["status"] == "failed"}
    assert not failed, failed
    store = open_store(tmp_path / "store")
    tasks = [t for t in summary.plan.tasks if t.flight is not None]
    return {t.step: store.load(t.key, t.stage) for t in tasks}, summary.plan


def test_new_stages_run_store_and_read_back_what_the_library_computes(tmp_path):
    rec, p = _records(tmp_path, SIMULATED + NEW)
    data = rec["load"]
    regress = aeroid.stepwise_regression(data, "q", ["alpha", "elevator", "alpha*q"])
    assert isinstance(rec["regress"], aeroid.StepwiseResult)
    assert rec["regress"].selected == regress.selected
    assert rec["regress"].regression.parameters == pytest.approx(
        regress.regression.parameters, rel=1e-12
    )
    assert rec["regress"].regression.press == pytest.approx(regress.regression.press, rel=1e-12)
    response = aeroid.composite_response(
        data, ["elevator"], ["q", "alpha"], frequency_range=(1.0, 30.0), windows=[10.0, 5.0]
    )
    stored = rec["frequency_id"]
    assert isinstance(stored, aeroid.CompositeResponse)
    np.testing.assert_allclose(
        stored.channel("elevator", "q").response, response.channel("elevator", "q").response
    )
    fit = aeroid.fit_transfer_function(
        response, numerator_order=1, denominator_order=2, input="elevator", output="q"
    )
    assert isinstance(rec["transfer_function"], aeroid.TransferFunctionFit)
    assert rec["transfer_function"].parameters == pytest.approx(fit.parameters, rel=1e-9)
    fd = rec["frequency_identify"]
    assert isinstance(fd, aeroid.FrequencyDomainResult)
    # seeded recovery of the flight's truth (the simulated metadata) within 4 sigma
    truth = data.metadata["truth"]
    for name in ("M_alpha", "M_q", "M_delta"):
        assert abs(fd.parameters[name] - truth[name]) < 4 * fd.stderr[name], name
    hq = rec["handling_qualities"]
    assert isinstance(hq, HandlingQualities) and hq.bandwidth is None and hq.margins is None
    loes = aeroid.equivalent_system(response, kind="short_period", input="elevator", output="q")
    assert hq.equivalent_system.parameters == pytest.approx(loes.parameters, rel=1e-9)
    assert "Low-order equivalent system" in hq.summary()
    # the flight's report renders every analysis that ran, from its summary
    markdown = rec["report"].markdown
    for heading in (
        "Regression",
        "Frequency responses",
        "Transfer-function fit",
        "Frequency-domain identification",
        "Handling qualities",
    ):
        assert f"\n## {heading}\n" in markdown, heading
    assert "## Data compatibility" not in markdown
    # the loaded data's checks come first: one line for a clean record, the table otherwise
    quality = data.metadata["quality"]
    assert markdown.index("## Data quality") < markdown.index("## Regression")
    assert ("no flags on 3 channels" in markdown) == quality.ok
    assert ("| channel | samples |" in markdown) == (not quality.ok)
    # the campaign report sets each flight's equivalent system against its condition
    campaign = (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    table = campaign.split("### Handling qualities", 1)[1]
    assert "| omega [rad/s] |" in table and "| zeta [-] |" in table
    level = hq.equivalent_system.level.level
    assert "| LOES level [MIL-STD-1797A] |" in table and f"Level {level}" in hq.summary()
    omega = hq.equivalent_system.parameters["omega"]
    assert f"{omega:.4g}" in table.split("\n\n")[2]
    # none of the new steps feeds identify without compatibility: its input is as loaded
    identify = next(t for t in p.tasks if t.step == "identify")
    assert set(identify.upstream) == {"data"}


def test_without_the_new_stages_no_step_is_planned_for_them(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(SIMULATED)
    steps = {t.step for t in plan(cfg).tasks}
    assert steps.isdisjoint(
        {"compatibility", "regress", "frequency_id", "transfer_function", "handling_qualities"}
    )


def test_equation_error_regress_and_its_stepwise_only_options(tmp_path):
    opts = STAGES["regress"].options
    with pytest.raises(ValueError, match="f_in: only for method stepwise"):
        opts.model_validate({"response": "q", "method": "equation_error", "f_in": 2.0})
    text = SIMULATED + (
        "  regress: {response: q, candidates: [alpha, elevator], method: equation_error}\n"
    )
    rec, _ = _records(tmp_path, text)
    direct = aeroid.equation_error(rec["load"], "q", ["alpha", "elevator"])
    assert isinstance(rec["regress"], aeroid.RegressionResult)
    assert rec["regress"].parameters == pytest.approx(direct.parameters, rel=1e-12)
    assert np.isfinite(direct.press)  # the stored record keeps its PRESS
    assert rec["regress"].press == pytest.approx(direct.press, rel=1e-12)


def test_handling_qualities_needs_something_to_compute():
    opts = STAGES["handling_qualities"].options
    with pytest.raises(ValueError, match="all off"):
        opts.model_validate({"bandwidth": False})


def _run_stage(name: str, options: dict, inputs: dict, **ctx: object) -> object:
    stage = STAGES[name]
    return stage.run(
        StageContext(options=stage.options.model_validate(options), inputs=inputs, **ctx)
    )


def test_bandwidth_and_margins_of_a_known_loop_round_trip_through_the_codec():
    # the rate response of K / (s (s + a)) sampled noise-free: a pure closed form
    t = np.arange(0, 60.0, 0.02)
    rng = np.random.default_rng(11)
    u = rng.standard_normal(t.size)
    k, a = 4.0, 2.0
    # x'' + a x' = k u; the output is the rate x' (first order: y' = -a y + k u)
    y = np.zeros_like(t)
    for i in range(1, t.size):
        e = np.exp(-a * 0.02)
        y[i] = e * y[i - 1] + k / a * (1 - e) * u[i - 1]
    data = aeroid.FlightData(t, {"u": u, "y": y})
    response = aeroid.composite_response(data, ["u"], ["y"], frequency_range=(0.3, 30.0))
    hq = _run_stage(
        "handling_qualities",
        {"kind": "rate", "input": "u", "output": "y", "margins": True},
        {"response": response},
    )
    assert isinstance(hq, HandlingQualities)
    direct = aeroid.bandwidth(response, kind="rate", input="u", output="y")
    assert hq.bandwidth.bandwidth == pytest.approx(direct.bandwidth, rel=1e-12)
    # the margins of L = k / (s (s + a)): crossover where k = w sqrt(w^2 + a^2)
    wc = np.sqrt((-(a**2) + np.sqrt(a**4 + 4 * k**2)) / 2)
    margins = _run_stage(
        "handling_qualities",
        {"bandwidth": False, "margins": True, "input": "u", "output": "y"},
        {"response": (np.array([k]), np.array([1.0, a, 0.0]))},
    )
    assert margins.margins.gain_crossover == pytest.approx(wc, rel=1e-3)
    arrays, tree = encode(hq)
    back = decode(arrays, tree)
    assert isinstance(back, HandlingQualities)
    assert back.bandwidth.bandwidth == hq.bandwidth.bandwidth


@pytest.mark.slow
def test_compatibility_corrects_the_data_identify_and_validate_read(tmp_path):
    data = simulated_flight(12.0, 25.0, errors=BIASES, seed=3)
    names = list(data.channels)
    table = np.column_stack([data.time, *(data.channels[n] for n in names)])
    csv = tmp_path / "flight.csv"
    np.savetxt(csv, table, delimiter=",", header=",".join(["time", *names]), comments="")
    # identify reads `corrected` where compatibility runs: planned so, keyed on it
    cfg = tmp_path / "plan.yaml"
    cfg.write_text(SIMULATED.replace("stages:\n", "stages:\n  compatibility: {}\n"))
    p = plan(cfg)
    keys = {t.step: t.key for t in p.tasks}
    for step in ("identify", "validate"):
        task = next(t for t in p.tasks if t.step == step)
        assert task.upstream["corrected"] == keys["compatibility"], step
    # a pipeline of load -> compatibility -> regress on the corrected data, from a file
    (tmp_path / "pipelines").mkdir()
    (tmp_path / "pipelines" / "compat.py").write_text(
        "from aeroid.pipeline import Pipeline, Step\n"
        "pipeline = Pipeline(name='compat', flight_steps=(\n"
        "    Step('load'), Step('compatibility', inputs={'data': 'load'}),\n"
        "    Step('regress', inputs={'data': 'load', 'corrected': 'compatibility'}),\n"
        "))\n"
    )
    text = (
        "model: short_period\npipeline: compat\nseed: 3\nstore: store\nreport: out/r.md\n"
        "flights: [{path: flight.csv}]\n"
        "stages:\n  compatibility: {estimate: [b_p, b_q, b_r], n_draws: 10}\n"
        "  regress: {response: q, candidates: [p, r], method: equation_error}\n"
    )
    rec, p = _records(tmp_path, text)
    checked = rec["compatibility"]
    assert isinstance(checked, aeroid.CompatibilityResult)
    for name in ("b_p", "b_q", "b_r"):
        # the injected gyro biases, within 4 sigma
        assert abs(checked.parameters[name] - BIASES[name]) < 4 * checked.stderr[name], name
    fit = aeroid.equation_error(checked.corrected, "q", ["p", "r"])
    assert rec["regress"].parameters == pytest.approx(fit.parameters, rel=1e-12)


def _px4_config(tmp_path: Path) -> Path:
    text = (ROOT / "configs" / "px4_roll.yaml").read_text(encoding="utf-8")
    log = ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg"
    text = text.replace("../tests/data/px4/sample_log_small.ulg", str(log))
    text = re.sub(r"^store: .*$", "store: store", text, count=1, flags=re.M)
    text = text.replace("report: ../reports/px4_roll.md", "report: out/px4_roll.md")
    # the flight condition the campaign report trends against rides along in the metadata
    text = text.replace(
        "    sample_rate: 100 ", "    condition: {airspeed: 12.0}\n    sample_rate: 100 "
    )
    cfg = tmp_path / "px4_roll.yaml"
    cfg.write_text(text)
    return cfg


def test_px4_roll_campaign_runs_end_to_end_through_the_channel_map(tmp_path):
    cfg = _px4_config(tmp_path)
    rec, _ = _records(tmp_path, cfg.read_text())
    data = rec["load"]
    assert set(data.channels) == {"y", "u"}
    assert data.metadata["airspeed"] == 12.0
    assert data.sample_rate == pytest.approx(100.0)
    assert data.time[0] >= 23.4 - 1e-9 and data.time[-1] <= 25.0 + 1e-9
    direct = aeroid.load_mapped(
        ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg",
        {
            "y": {"channel": "vehicle_angular_velocity.xyz[0]", "unit": "rad/s"},
            "u": {"channel": "actuator_controls_0.control[0]"},
        },
        sample_rate=100,
        window=[23.4, 25.0],
    )
    np.testing.assert_array_equal(data.channels["y"], direct.channels["y"])
    # the log's channels are checked as they arrive: on their own ~400 Hz stamps,
    # inside the window, under the log's names; the flight's report shows it first
    quality = data.metadata["quality"]
    assert set(quality.channels) == {
        "vehicle_angular_velocity.xyz[0]",
        "actuator_controls_0.control[0]",
    }
    gyro = quality["vehicle_angular_velocity.xyz[0]"]
    assert 350 < gyro.rate < 450 and gyro.n_samples > 1.5 * data.n_samples
    assert gyro.dropouts == 0  # the 0.16 s gap at 20.3 s lies outside the window
    text = rec["report"].markdown
    assert text.index("Data quality") < text.index("Identification")
    campaign = (tmp_path / "out" / "px4_roll.md").read_text()
    for flag in quality.flags["vehicle_angular_velocity.xyz[0]"]:
        assert f"data {flag}" in campaign
    fit = rec["identify"]
    assert fit.parameters["tau"] > 0  # roll damping L_p = -1/tau is negative
    assert (tmp_path / "out" / "px4_roll.md").is_file()


def test_load_merges_the_flight_condition_into_the_metadata():
    stage = STAGES["load"]
    log = ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg"
    from aeroid.pipeline.keys import file_digest

    opts = {
        "channels": ["vehicle_angular_velocity.xyz[0]"],
        "sample_rate": 50.0,
        "window": [23.4, 25.0],
        "condition": {"airspeed": 12.0},
    }
    source = {"kind": "file", "path": str(log), "sha256": file_digest(log)}
    data = stage.run(
        StageContext(options=stage.options.model_validate(opts), inputs={}, source=source)
    )
    assert data.metadata["airspeed"] == 12.0 and "window" in data.metadata
    with pytest.raises(ValueError):
        stage.options.model_validate({"sample_rate": 0.0})
    # unset, the options added for logs leave the load key's document unchanged
    assert set(stage.options.model_validate({}).key_document()) == {
        "time_column",
        "channels",
        "units",
        "quality",
    }
