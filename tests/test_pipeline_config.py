"""Campaign configs: validation errors name the file, key path and expectation."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from aeroid.errors import ConfigError
from aeroid.model import Model
from aeroid.pipeline import load_config, plan, resolve_model

ROOT = Path(__file__).resolve().parents[1]


def _write(tmp: Path, text: str, name: str = "camp.yaml") -> Path:
    p = tmp / name
    p.write_text(text)
    return p


def test_minimal_config_and_relative_paths(tmp_path):
    cfg = load_config(_write(tmp_path, "model: short_period\nflights: ['data/*.csv']\n"))
    assert cfg.store_path == tmp_path / ".aeroid-store"
    assert cfg.report_path == tmp_path / ".aeroid-store" / "reports" / "camp.md"
    assert cfg.campaign_name == "camp"
    assert cfg.resolve("data/x.csv") == tmp_path / "data" / "x.csv"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "model: short_period\nflights: [a.csv]\nstorre: x\n",
            r"camp.yaml: storre: unknown key; allowed keys: .*store",
        ),
        (
            "model: short_period\nflights: [{path: a.csv, tim_column: t}]\n",
            r"camp.yaml: flights\[0\].tim_column: unknown key; allowed keys: channels, path, time_column, units",
        ),
        (
            "model: short_period\nflights: [{simulated: {n_flights: 0}}]\n",
            r"camp.yaml: flights\[0\].simulated.n_flights: Input should be greater than or equal to 1",
        ),
        ("flights: [a.csv]\n", r"camp.yaml: model: required key is missing"),
        (
            "model: short_period\nflights: [a.csv]\nworkers: many\n",
            r"camp.yaml: workers: .*integer",
        ),
        (
            "model: short_period\nflights: [a.csv]\nscheduler: localhost\n",
            r"camp.yaml: scheduler: .*tcp://",
        ),
        ("- just\n- a list\n", r"camp.yaml: expected a mapping"),
        ("model: [unclosed\n", r"camp.yaml: line 2.*not valid YAML"),
    ],
)
def test_errors_name_file_key_path_and_expectation(tmp_path, text, expected):
    with pytest.raises(ConfigError, match=expected):
        load_config(_write(tmp_path, text))


def test_stage_options_are_validated_with_their_key_path(tmp_path):
    p = _write(
        tmp_path,
        "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n"
        "stages:\n  identify:\n    max_iterations: 10\n    metod: lm\n",
    )
    with pytest.raises(
        ConfigError,
        match=r"camp.yaml: stages.identify.metod: unknown key; allowed keys: .*max_iterations",
    ):
        plan(p)
    p = _write(
        tmp_path,
        "model: short_period\nflights: [{simulated: {n_flights: 2}}]\nstages: {identfy: {}}\n",
    )
    with pytest.raises(
        ConfigError, match=r"stages.identfy: unknown stage; pipeline 'campaign' has load, identify"
    ):
        plan(p)
    p = _write(
        tmp_path,
        "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n"
        "stages: {validate: {confidence: 2}}\n",
    )
    with pytest.raises(
        ConfigError, match=r"stages.validate.confidence: Input should be less than 1"
    ):
        plan(p)


def test_missing_flights_and_patterns_are_reported(tmp_path):
    p = _write(tmp_path, "model: short_period\nflights: ['nothing/*.csv']\n")
    with pytest.raises(
        ConfigError, match=r"flights\[0\]: the pattern 'nothing/\*.csv' matches no file"
    ):
        plan(p)


def test_models_by_builtin_name_and_import_path(tmp_path):
    assert resolve_model("short_period").name == "short_period"
    (tmp_path / "my_vehicle.py").write_text(
        "import numpy as np\nfrom aeroid import Model\n"
        "def build():\n"
        "    return Model(['y'], ['u'], {'k': 1.0}, lambda t, x, u, p: np.array([-p['k'] * x[0] + u[0]]), name='lag')\n"
        "MODEL = build()\nNOT_A_MODEL = 3\n"
    )
    m = resolve_model("my_vehicle:build", str(tmp_path))
    assert isinstance(m, Model) and m.name == "lag"
    assert resolve_model("my_vehicle:MODEL", str(tmp_path)).name == "lag"
    with pytest.raises(ConfigError, match="expected a Model"):
        resolve_model("my_vehicle:NOT_A_MODEL", str(tmp_path))
    with pytest.raises(ConfigError, match="has no attribute"):
        resolve_model("my_vehicle:nothing", str(tmp_path))
    with pytest.raises(ConfigError, match="built-in model"):
        resolve_model("concorde")


def test_the_demo_config_is_valid_and_plans_every_stage():
    the_plan = plan(ROOT / "configs" / "demo.yaml")
    steps = {t.step for t in the_plan.tasks}
    assert {"load", "identify", "validate", "propagate", "report", "campaign_report"} <= steps
    assert len(the_plan.flights) >= 12


def test_simulated_flights_fly_a_doublet_or_a_doublet_and_a_sweep():
    import numpy as np

    from aeroid import catalog
    from aeroid.pipeline.synthetic import flight_spec, fly

    base = {"n_flights": 12, "seed": 7, "duration": 20.0}
    doublet = flight_spec(base, 3)
    # the original manoeuvre is not named, so the load keys of earlier campaigns stay
    assert "maneuver" not in doublet
    assert flight_spec({**base, "maneuver": "doublet"}, 3) == doublet
    swept = flight_spec({**base, "maneuver": "doublet_sweep"}, 3)
    assert swept == {**doublet, "maneuver": "doublet_sweep"}
    d, s = fly(doublet), fly(swept)
    t = d.time
    np.testing.assert_array_equal(d["elevator"], catalog.doublet(t))
    np.testing.assert_array_equal(s["elevator"][t < 4.0], catalog.doublet(t)[t < 4.0])
    # a linear sweep from 0.2 to 3 Hz over the last 16 s crosses zero 2 * (0.2 + 3) / 2 * 16
    # = 51.2 times
    tail = s["elevator"][t >= 4.0]
    crossings = np.count_nonzero(np.diff(np.signbit(tail[1:])))
    assert abs(crossings - 51.2) <= 1.5
    assert np.max(np.abs(tail)) == pytest.approx(0.05, rel=1e-3)


def test_the_sweep_gives_coherent_frequency_checks_and_closer_estimates():
    # the demo's flights with and without the sweep: the frequency check finds coherent
    # data on most flights only with it, and the estimates land nearer the truth
    import warnings

    import numpy as np

    import aeroid
    from aeroid import catalog
    from aeroid.pipeline.synthetic import flight_spec, fly

    model = catalog.short_period()
    names = ["Z_alpha", "M_alpha", "M_q", "M_delta"]
    result = {}
    for maneuver, duration in (("doublet", 10.0), ("doublet_sweep", 20.0)):
        spec = {"n_flights": 12, "seed": 7, "duration": duration, "maneuver": maneuver}
        warned, errors = 0, []
        for i in range(12):
            data = fly(flight_spec(spec, i))
            truth = data.metadata["truth"]
            fit = aeroid.identify(model, data, names, estimate_x0=True)
            errors += [abs(fit.parameters[n] / truth[n] - 1.0) for n in names]
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                aeroid.frequency_response(model, data, fit, frequency_range=(0.2, 3.0))
            warned += any("coherent" in str(w.message) for w in caught)
        result[maneuver] = (warned, float(np.mean(errors)), max(errors))
    assert result["doublet_sweep"][0] <= 3 < result["doublet"][0]
    assert result["doublet_sweep"][1] < result["doublet"][1]
    assert result["doublet_sweep"][2] < 0.05


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # NaN and infinity are refused where they are written, not at run time
        (
            "stages:\n  identify: {weights: {alpha: 1.0, q: .nan}}\n",
            r"camp.yaml: stages.identify.weights.q: Input should be a finite number",
        ),
        (
            "stages:\n  identify: {simulate_options: {rtol: [1.0, .inf]}}\n",
            r"camp.yaml: stages.identify.simulate_options: must be a finite number "
            r"\(at rtol\[1\]: inf\)",
        ),
        (
            "stages:\n  infer: {priors: {M_q: {normal: [.nan, 1.0]}}}\n",
            r"camp.yaml: stages.infer.priors.M_q.normal\[0\]: Input should be a finite number",
        ),
        # required keywords of the library function are required options
        ("stages:\n  filter: {}\n", r"stages.filter.process_noise: required key is missing"),
        # a manoeuvre its options cannot make
        (
            "stages:\n  design: {maneuver: {type: doublet, control: elevator, options: {}}}\n",
            r"stages.design.maneuver: options do not make a doublet: .*amplitude",
        ),
        (
            "stages:\n  design: {maneuver: {type: multisine, control: elevator, "
            "options: {bogus: 1}}}\n",
            r"stages.design.maneuver: options do not make a multisine: .*bogus",
        ),
    ],
)
def test_stage_options_that_cannot_run_are_refused_when_planning(tmp_path, text, expected):
    cfg = _write(tmp_path, "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n" + text)
    with pytest.raises(ConfigError, match=expected):
        plan(cfg)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("airspeed: [120, -60]", r"simulated.airspeed\[1\]: Input should be greater than 0"),
        ("airspeed: [.nan, 100]", r"simulated.airspeed\[0\]: Input should be a finite number"),
        ("duration: .inf", r"simulated.duration: Input should be a finite number"),
        ("duration: 1.0e+9", r"simulated: duration x sample_rate gives 5e\+10 samples"),
        ("noise: {beta: 0.01}", r"simulated.noise.beta: Input should be 'alpha' or 'q'"),
        ("noise: {alpha: -1}", r"simulated.noise.alpha: Input should be greater than or equal"),
        ("seed: -5", r"simulated.seed: Input should be greater than or equal to 0"),
    ],
)
def test_simulated_flights_refuse_absurd_conditions(tmp_path, spec, expected):
    text = f"model: short_period\nflights: [{{simulated: {{n_flights: 2, {spec}}}}}]\n"
    with pytest.raises(ConfigError, match=r"camp.yaml: flights\[0\]\." + expected):
        load_config(_write(tmp_path, text))


def test_yaml_errors_are_one_line_and_a_key_given_twice_is_refused(tmp_path):
    with pytest.raises(ConfigError) as bad:
        load_config(_write(tmp_path, "model: short_period\nflights: [a.csv\n"))
    assert "\n" not in str(bad.value) and "line 3" in str(bad.value)
    twice = "model: short_period\nflights: [a.csv]\nmodel: first_order\n"
    with pytest.raises(ConfigError, match=r"line 3, column 1: .*the key 'model' is given twice"):
        load_config(_write(tmp_path, twice))
    nested = "model: short_period\nflights: [{simulated: {seed: 1, seed: 2}}]\n"
    with pytest.raises(ConfigError, match=r"the key 'seed' is given twice"):
        load_config(_write(tmp_path, nested))
    with pytest.raises(ConfigError, match=r"seed: Input should be greater than or equal to 0"):
        load_config(_write(tmp_path, "model: short_period\nflights: [a.csv]\nseed: -1\n"))


def test_the_same_flight_listed_twice_is_refused(tmp_path):
    twice = (
        "model: short_period\nflights: [{simulated: {n_flights: 2}}, {simulated: {n_flights: 2}}]\n"
    )
    with pytest.raises(ConfigError, match=r"'sim-0#2' is the same simulated flight as 'sim-0'"):
        plan(_write(tmp_path, twice))
    # two simulated campaigns that differ are two sets of flights
    other = twice.replace("{n_flights: 2}}]", "{n_flights: 2, seed: 4}}]")
    assert len(plan(_write(tmp_path, other)).flights) == 4
    (tmp_path / "a.csv").write_text("time,alpha,q,elevator\n0,0,0,0\n0.1,0,0,0\n")
    (tmp_path / "sub").mkdir()
    shutil.copy(tmp_path / "a.csv", tmp_path / "sub" / "copy.csv")
    files = "model: short_period\nflights: [a.csv, 'sub/*.csv']\n"
    with pytest.raises(
        ConfigError, match=r"'copy' \(.*copy.csv\) has the same contents and loader options as 'a'"
    ):
        plan(_write(tmp_path, files))
