"""Campaign configs: validation errors name the file, key path and expectation."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import ConfigError
from aeroid.models.model import Model
from aeroid.pipeline import load_config, plan, resolve_model, run

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
            r"camp.yaml: flights\[0\].tim_column: unknown key; allowed keys: allow_external_data, channels, condition, max_gap, model, path, sample_rate, segments, time_column, units, window",
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
        ConfigError,
        match=r"stages.identfy: unknown stage; pipeline 'campaign' has load, .*identify",
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
    the_plan = plan(ROOT / "configs" / "short_period.yaml")
    steps = {t.step for t in the_plan.tasks}
    assert {"load", "identify", "validate", "propagate", "report", "campaign_report"} <= steps
    assert len(the_plan.flights) >= 12


def test_the_jsbsim_demo_plans_each_flight_with_its_own_trim_model():
    the_plan = plan(ROOT / "configs" / "demo.yaml")
    # twelve flights fitted by the database, two held out (issue 51)
    assert len(the_plan.flights) == 14
    identify = [t for t in the_plan.tasks if t.step == "identify"]
    # each flight is fitted with the model at its own trim: fourteen model fingerprints
    assert len({repr(t.document["model"]) for t in identify}) == 14
    steps = {t.step for t in the_plan.tasks}
    # all eight steps of the chain, and the database
    chain = {"load", "identify", "filter", "validate", "propagate", "infer", "design", "report"}
    assert chain | {"database"} <= steps
    # the posterior and the next manoeuvre on the flights their `flights` names only
    assert [t.flight for t in the_plan.tasks if t.step == "infer"] == ["flight_03"]
    assert [t.flight for t in the_plan.tasks if t.step == "design"] == ["flight_08"]
    # the trim angle of attack of every flight lies in 0-10 deg
    import math

    alphas = [f.condition["alpha"] for f in the_plan.config.flights]
    assert min(alphas) < math.radians(1.0) and math.radians(9.0) < max(alphas) < math.radians(10.5)


def test_simulated_flights_fly_a_doublet_or_a_doublet_and_a_sweep():
    import numpy as np

    from aeroid.models import catalog
    from aeroid.pipeline.plans.synthetic import flight_spec, fly

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
    # the demo's flights with and without the sweep: the frequency check (at the
    # config's 5.12 s segments) finds resolved, coherent q data on most flights only
    # with it, and the estimates land nearer the truth. α falls as 1/f² above the
    # 0.48 Hz mode: 0.2 Hz bins resolve it (15 % steps) only above 2.7 Hz.
    import warnings

    import numpy as np

    import aeroid
    from aeroid.models import catalog
    from aeroid.pipeline.plans.synthetic import flight_spec, fly

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
                aeroid.frequency_response(
                    model, data, fit, frequency_range=(0.2, 3.0), nperseg=256, outputs=["q"]
                )
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
        (
            "stages:\n  infer: {priors: {M_q: {normal: [-2.0, -1.0]}}}\n",
            r"camp.yaml: stages.infer.priors.M_q: .*Normal: sigma must be > 0, got -1.0",
        ),
        (
            "stages:\n  infer: {priors: {M_q: {uniform: [2.0, 1.0]}}}\n",
            r"stages.infer.priors.M_q: .*Uniform: lo must be < hi",
        ),
        # required keywords of the library function are required options
        ("stages:\n  filter: {}\n", r"stages.filter.process_noise: required key is missing"),
        # what every flight's task would refuse at run time
        ("stages:\n  identify: {method: nonsense}\n", r"stages.identify.method: Input should"),
        (
            "stages:\n  identify: {parameters: [M_q, M_q]}\n",
            r"stages.identify.parameters: .*\['M_q'\] listed more than once",
        ),
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
        (
            "stages:\n  design: {maneuver: {type: multistep, control: elevator, "
            "options: {amplitude: 0.05, widht: 1.0}}}\n",
            r"stages.design.maneuver: options do not make a multistep: .*widht",
        ),
        (
            "stages:\n  design: {maneuver: {type: multistep, control: elevator, "
            "options: {amplitude: 0.05, pattern: [3, 0, 1]}}}\n",
            r"options do not make a multistep: Multistep pattern: .*positive integers",
        ),
        (
            "stages:\n  design: {maneuver: {type: chirp, control: elevator, "
            "options: {f0: 0.1, f1: 2.0, amplitude: 0.05, sweep: log}}}\n",
            r"options do not make a chirp: Chirp sweep: expected 'linear' or 'exponential'",
        ),
        (
            "stages:\n  design: {maneuver: {type: multistep, control: elevator, "
            "options: {amplitude: 0.05, width: 0.5}}}\n",
            r"stages.design.maneuver: a multistep with every option fixed has nothing to design",
        ),
        (
            "stages:\n  design: {optimizer_options: {maxiter: 3, wobble: 2}, maneuver: "
            "{type: doublet, control: elevator, options: {amplitude: [0.0, 0.05]}}}\n",
            r"stages.design.optimizer_options: unknown keys \['wobble'\]",
        ),
        (
            "stages:\n  design: {maneuver: {type: staircase, control: elevator}}\n",
            r"stages.design.maneuver.type: Input should be .*'multistep'",
        ),
    ],
)
def test_stage_options_that_cannot_run_are_refused_when_planning(tmp_path, text, expected):
    cfg = _write(tmp_path, "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n" + text)
    with pytest.raises(ConfigError, match=expected):
        plan(cfg)


def test_a_config_designs_a_3211_or_an_exponential_sweep(tmp_path):
    from aeroid.pipeline.stages.config_specs import ManeuverSpec
    from aeroid.uncertainty.maneuvers import Chirp, Multistep

    stage = (
        "stages:\n  design:\n    maneuver: {type: multistep, control: elevator, "
        "options: {amplitude: [0.0, 0.05], width: [0.3, 1.0], pattern: [3, 2, 1, 1]}}\n"
    )
    cfg = _write(tmp_path, "model: short_period\nflights: [{simulated: {n_flights: 1}}]\n" + stage)
    (task,) = [t for t in plan(cfg).tasks if t.step == "design"]
    assert task.document["stage_version"] == "5"  # 5: the Multisine phases in frequency order
    spec = load_config(cfg).stages["design"]["maneuver"]
    family = ManeuverSpec.model_validate(spec).build()
    assert isinstance(family, Multistep) and family.pattern == (3, 2, 1, 1)
    assert family.variable_names == ("amplitude", "width")
    sweep = ManeuverSpec.model_validate(
        {
            "type": "chirp",
            "control": "elevator",
            "options": {"f0": 0.1, "f1": [1.0, 3.0], "amplitude": 0.05, "sweep": "exponential"},
        }
    ).build()
    assert isinstance(sweep, Chirp) and sweep.sweep == "exponential"


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


# -- hostile files: refused with the file named, never a traceback or a hang ----------------


@contextlib.contextmanager
def _deadline(seconds: float) -> Iterator[None]:
    """Fail (rather than hang the suite) when the body runs longer than `seconds`."""

    def expired(signum: int, frame: object) -> None:
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


_VALID = "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n"


def _alias_bomb(depth: int) -> str:
    """Nine aliases of the level below per level: 9**(depth + 1) values from a few lines."""
    lines = ["    a: &a [x, x, x, x, x, x, x, x, x]"]
    for i in range(depth):
        prev, cur = chr(97 + i), chr(98 + i)
        lines.append(f"    {cur}: &{cur} [" + ", ".join([f"*{prev}"] * 9) + "]")
    return _VALID + "stages:\n  identify:\n    simulate_options:\n" + "\n".join(lines) + "\n"


def test_a_yaml_alias_bomb_is_refused_at_its_first_anchor(tmp_path):
    with _deadline(5.0), pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, _alias_bomb(7)))
    assert str(err.value) == (
        f"{tmp_path / 'camp.yaml'}: line 6, column 8: YAML anchors and aliases (&name, *name) "
        "are not accepted in a campaign config; write the values out"
    )
    # a merge key is an alias too
    merged = _VALID + "base: &base {n: 1}\nstages: {identify: {<<: *base}}\n"
    with pytest.raises(ConfigError, match=r"line 3, column 7: YAML anchors and aliases"):
        load_config(_write(tmp_path, merged))


def test_a_binary_config_is_refused(tmp_path):
    p = tmp_path / "camp.yaml"
    p.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8)))
    with pytest.raises(ConfigError, match=r"camp.yaml: not UTF-8 text .*; is it a binary file\?"):
        load_config(p)
    p.write_bytes(_VALID.encode() + b"\x00\x01\x02")  # valid UTF-8, but NUL bytes
    with pytest.raises(ConfigError, match=r"camp.yaml: not UTF-8 text \(a NUL byte at line 3\)"):
        load_config(p)


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-le", "utf-16-be"])
def test_a_utf16_config_is_refused_naming_the_encoding(tmp_path, codec):
    p = tmp_path / "camp.yaml"
    p.write_bytes(_VALID.encode(codec))
    with pytest.raises(
        ConfigError, match=r"camp.yaml: not UTF-8 text .*it looks like UTF-16: save it as UTF-8"
    ):
        load_config(p)
    # UTF-8 with a byte-order mark is UTF-8
    p.write_bytes(_VALID.encode("utf-8-sig"))
    assert load_config(p).model == "short_period"


def test_a_5000_deep_list_is_refused(tmp_path):
    deep = _VALID + "name: " + "[" * 5000 + "]" * 5000 + "\n"
    with (
        _deadline(20.0),
        pytest.raises(
            ConfigError, match=r"camp.yaml: line 3, column 106: nested deeper than 100 levels"
        ),
    ):
        load_config(_write(tmp_path, deep))
    # block style likewise; 100 levels are read
    block = _VALID + "x:\n" + "".join("  " * i + "-\n" for i in range(1, 120))
    with pytest.raises(ConfigError, match=r"line 103, .*nested deeper than 100 levels"):
        load_config(_write(tmp_path, block))
    ok = _VALID + "stages: {identify: {simulate_options: {x: " + "[" * 96 + "]" * 96 + "}}}\n"
    assert load_config(_write(tmp_path, ok)).stages["identify"] is not None


def test_a_config_that_is_a_directory_or_a_special_file_is_refused(tmp_path):
    (tmp_path / "dir.yaml").mkdir()
    with pytest.raises(ConfigError, match=r"dir.yaml: is a directory, not a config file"):
        load_config(tmp_path / "dir.yaml")
    os.mkfifo(tmp_path / "pipe.yaml")  # reading it would wait for a writer forever
    with (
        _deadline(5.0),
        pytest.raises(ConfigError, match=r"pipe.yaml: is a FIFO \(named pipe\), not a config file"),
    ):
        load_config(tmp_path / "pipe.yaml")
    with _deadline(5.0), pytest.raises(ConfigError, match=r"^/dev/zero: is a device"):
        load_config("/dev/zero")
    with pytest.raises(ConfigError, match=r"nothing.yaml: cannot read the config file \(No such"):
        load_config(tmp_path / "nothing.yaml")


def test_a_huge_config_or_one_holding_data_is_refused(tmp_path):
    big = _VALID + "# " + "x" * (300 * 1024) + "\n"
    with pytest.raises(
        ConfigError, match=r"camp.yaml: \d+ bytes; a config file is at most 256 KiB"
    ):
        load_config(_write(tmp_path, big))
    values = _VALID + "name: [" + "0, " * 6000 + "]\n"
    with _deadline(20.0), pytest.raises(ConfigError, match=r"line 3, .*more than 5000 values"):
        load_config(_write(tmp_path, values))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("name: 2024-13-45\n", r"line 3, column 7: cannot read the value \(month must be in"),
        ("seed: " + "9" * 5000 + "\n", r"line 3, column 7: cannot read the value \(Exceeds"),
        ("? [a, b]\n: 1\n", r"line 3, column 3: a key must be a single value"),
        ("name: !!python/object:os.system {}\n", r"line 3, column 7: not valid YAML"),
    ],
)
def test_values_yaml_cannot_build_are_refused_at_their_line(tmp_path, text, expected):
    with pytest.raises(ConfigError, match=r"camp.yaml: " + expected):
        load_config(_write(tmp_path, _VALID + text))


def test_imports_are_off_unless_the_config_allows_them(tmp_path):
    assert load_config(_write(tmp_path, _VALID)).allow_imports is False
    assert load_config(_write(tmp_path, _VALID + "allow_imports: true\n")).allow_imports is True
    with pytest.raises(ConfigError, match=r"allow_imports: Input should be a valid boolean"):
        load_config(_write(tmp_path, _VALID + "allow_imports: maybe\n"))


# -- flight logs: channel maps, windows, segmentation -------------------------------------


def _csv_flight(path: Path) -> Path:
    t = np.arange(0.0, 2.0, 0.1)
    rows = "\n".join(f"{ti:.1f},{0.01 * i},{0.02 * i},0.0" for i, ti in enumerate(t))
    path.write_text("time,alpha,q,elevator\n" + rows + "\n")
    return path


def test_log_options_left_unset_change_no_flight_options_or_keys(tmp_path):
    from aeroid.pipeline.plans.config import FileFlights

    _csv_flight(tmp_path / "f1.csv")
    text = "model: short_period\nflights:\n  - {path: f1.csv, channels: {alpha: alpha, q: q, elevator: elevator}}\n"
    cfg = load_config(_write(tmp_path, text))
    assert FileFlights(path="x.csv").loader_options() == {}
    load = next(t for t in plan(cfg).tasks if t.step == "load")
    # the options a file flight contributes are the ones it sets, as before the log options
    added = {"sample_rate", "max_gap", "window", "segments"}
    assert not added & set(load.options) and not added & set(load.document["options"])
    # the key is the one computed from the options that existed before
    from aeroid.pipeline.keys import task_key
    from aeroid.pipeline.stages import STAGES

    stage = STAGES["load"]
    old_options = {
        "time_column": None,
        "units": None,
        "channels": {"alpha": "alpha", "q": "q", "elevator": "elevator"},
        "quality": None,  # load 2: the data-quality check, on unless set false
    }
    key, _ = task_key(
        record_type=stage.record_type,
        stage=stage.name,
        stage_version=stage.version,
        options=old_options,
        upstream=load.document["upstream"],
        model=None,
        seed=None,
    )
    assert load.key == key


@pytest.mark.parametrize(
    ("flight", "expected"),
    [
        ("{path: a.ulg, window: [25.0, 23.0]}", r"flights\[0\]\.window: .*inverted"),
        ("{path: a.ulg, sample_rate: 0}", r"flights\[0\]\.sample_rate: .*greater than 0"),
        ("{path: a.ulg, max_gap: -1}", r"flights\[0\]\.max_gap: .*greater than 0"),
        (
            "{path: a.ulg, window: [1, 2], segments: {inputs: [u]}}",
            r"flights\[0\]: .*window or segments, not both",
        ),
        ("{path: a.ulg, segments: {margin: 1}}", r"flights\[0\]\.segments: .*one of inputs"),
        (
            "{path: a.ulg, window: {mode: 1, events: [a, b]}}",
            r"flights\[0\]\.window: .*one of mode",
        ),
        ("{path: a.ulg, channels: {p: {channel: x, sign: 2}}}", r"flights\[0\]\.channels\.p\.sign"),
        (
            "{path: a.ulg, channels: {p: {chanel: x}}}",
            r"flights\[0\]\.channels\.p\.chanel: unknown key",
        ),
        ("{path: a.ulg, segments: {inputs: [u], thresold: 3}}", r"segments\.thresold: unknown key"),
        # a flight condition's keys are the one list of aeroid._conditions
        (
            "{path: a.csv, condition: {airsped: 50}}",
            r"flights\[0\]\.condition\.airsped: .*'airspeed'.*did you mean 'airspeed'\?",
        ),
        ("{path: a.csv, condition: {Mach: 0.3}}", r"condition\.Mach: .*did you mean 'mach'\?"),
    ],
)
def test_log_options_are_validated_with_their_key_path(tmp_path, flight, expected):
    with pytest.raises(ConfigError, match=expected):
        load_config(_write(tmp_path, f"model: first_order\nflights:\n  - {flight}\n"))


def test_one_file_with_two_windows_is_two_flights(tmp_path):
    _csv_flight(tmp_path / "f1.csv")
    text = (
        "model: short_period\nflights:\n"
        "  - {path: f1.csv, window: [0.0, 1.0]}\n"
        "  - {path: f1.csv, window: [1.0, 1.9]}\n"
    )
    cfg = load_config(_write(tmp_path, text))
    files = cfg.expand_files()
    assert [spec.window for _, _, spec in files] == [(0.0, 1.0), (1.0, 1.9)]
    # the same flight listed again is refused, naming both entries; globs that
    # overlap keep a file once
    again = load_config(_write(tmp_path, text + "  - {path: f1.csv, window: [1.0, 1.9]}\n"))
    with pytest.raises(ConfigError, match=r"flights\[2\].*flights\[1\]"):
        again.expand_files()
    _csv_flight(tmp_path / "f2.csv")
    globs = load_config(
        _write(tmp_path, "model: short_period\nflights:\n  - 'f*.csv'\n  - 'f?.csv'\n")
    )
    assert [p.name for _, p, _ in globs.expand_files()] == ["f1.csv", "f2.csv"]


def test_the_px4_roll_config_plans_and_its_load_options_load_through_the_channel_map():
    pytest.importorskip("pyulog")
    from aeroid.io.channel_map import load_mapped

    cfg = load_config(ROOT / "configs" / "px4_roll.yaml")
    p = plan(cfg)
    assert [t.step for t in p.tasks] == [
        "load",
        "identify",
        "validate",
        "report",
        "campaign_report",
    ]
    (flight,) = [spec for _, _, spec in cfg.expand_files()]
    opts = flight.loader_options()
    assert opts == {
        "channels": {
            "y": {"channel": "vehicle_angular_velocity.xyz[0]", "unit": "rad/s"},
            "u": {"channel": "actuator_controls_0.control[0]"},
        },
        "sample_rate": 100.0,
        "window": [23.4, 25.0],
    }
    # the call the load stage makes (plain JSON options, as a task carries them)
    data = load_mapped(cfg.resolve(flight.path), **opts)
    assert data.names == ("y", "u") and data.n_samples == 161
    assert data.metadata["window"]["t0"] == 23.4
    model = resolve_model(cfg.model, cfg.base_dir)
    assert set(model.states) == {"y"} and set(model.controls) == {"u"}


def test_segments_of_a_config_give_the_windows_each_flight_is_made_of(tmp_path):
    pytest.importorskip("pyulog")
    from aeroid.io.channel_map import flight_windows, load_mapped

    log = ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg"
    text = f"""model: first_order
flights:
  - path: {log}
    channels:
      y: {{channel: "vehicle_angular_velocity.xyz[0]", unit: rad/s}}
      u: {{channel: "actuator_controls_0.control[0]"}}
    sample_rate: 100
    segments: {{inputs: [u], margin: 0.2, min_duration: 0.1, trim_window: 2.0, energy_window: 0.2}}
"""
    cfg = load_config(_write(tmp_path, text))
    (flight,) = [spec for _, _, spec in cfg.expand_files()]
    assert "segments" not in flight.loader_options()
    # the plan-time call, then one load per window (the options of each window's flight)
    windows = flight_windows(
        cfg.resolve(flight.path),
        flight.segments,
        channels=flight.channels,
        time_column=flight.time_column,
    )
    assert len(windows) == 2
    for t0, t1 in windows:
        data = load_mapped(
            cfg.resolve(flight.path), **{**flight.loader_options(), "window": [t0, t1]}
        )
        assert data.time[0] == pytest.approx(t0) and data.names == ("y", "u")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # a quoted number is refused where a number is meant, naming the key
        (
            "stages:\n  propagate: {n_samples: '100'}\n",
            r"camp.yaml: stages.propagate.n_samples: expected a number, not a string",
        ),
        ("stages:\n  propagate: {n_samples: true}\n", r"stages.propagate.n_samples: .*boolean"),
        ("stages:\n  infer: {n_ensembles: '2'}\n", r"stages.infer.n_ensembles: .*not a string"),
        ("stages:\n  identify: {tolerance: ' 1e-6'}\n", r"stages.identify.tolerance: .*string"),
        (
            "stages:\n  identify: {weights: {alpha: 1.0, q: '2'}}\n",
            r"stages.identify.weights: expected a number at q, got the string '2'",
        ),
        (
            "stages:\n  identify: {bounds: {M_q: [-10, 'true']}}\n",
            r"stages.identify.bounds.M_q\[1\]: Input should be a valid number",
        ),
        (
            "stages:\n  identify: {bounds: {M_q: ['-10', 0]}}\n",
            r"stages.identify.bounds: expected a number at M_q\[0\], got the string '-10'",
        ),
        (
            "stages:\n  identify: {bounds: {M_q: [true, 0]}}\n",
            r"stages.identify.bounds: expected a number at M_q\[0\], got the boolean true",
        ),
        ("seed: '7'\n", r"camp.yaml: seed: expected a number, not a string"),
        ("workers: '2'\n", r"camp.yaml: workers: expected a number, not a string"),
    ],
)
def test_quoted_numbers_and_booleans_are_refused_before_anything_runs(tmp_path, text, expected):
    cfg = _write(tmp_path, "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n" + text)
    with pytest.raises(ConfigError, match=expected):
        plan(cfg)
    with pytest.raises(ConfigError, match=expected):
        run(cfg, workers=0)
    assert not (tmp_path / ".aeroid-store").exists()  # nothing ran, nothing was stored


def test_a_quoted_flight_count_is_refused_and_numbers_stay_numbers(tmp_path):
    with pytest.raises(ConfigError, match=r"flights\[0\].simulated.n_flights: .*not a string"):
        load_config(
            _write(tmp_path, "model: short_period\nflights: [{simulated: {n_flights: '2'}}]\n")
        )
    # an int where a float is meant, and YAML 1.2 exponents (PyYAML reads 1e-6 as text)
    text = (
        "model: short_period\nflights: [{simulated: {n_flights: 2, duration: 4}}]\n"
        "stages:\n  identify: {tolerance: 1e-6, max_iterations: 20}\n"
        "  propagate: {n_samples: 2e2}\n"
        "  validate: {confidence: 0.9}\n"
    )
    p = plan(_write(tmp_path, text))
    opts = {t.step: t.options for t in p.tasks if t.flight is not None}
    assert opts["identify"]["tolerance"] == 1e-6 and opts["identify"]["max_iterations"] == 20
    assert opts["propagate"]["n_samples"] == 200
    flights = load_config(_write(tmp_path, text)).flights[0]
    assert flights.simulated.duration == 4.0  # type: ignore[union-attr]
    # a string option stays a string, and text that is not a number keeps pydantic's word
    with pytest.raises(ConfigError, match=r"stages.propagate.n_samples: .*valid integer"):
        plan(
            _write(
                tmp_path,
                "model: short_period\nflights: [{simulated: {n_flights: 2}}]\n"
                "stages:\n  propagate: {n_samples: many}\n",
            )
        )


def test_an_empty_parameter_list_is_the_librarys_not_every_parameter():
    """`parameters: []` fitted every parameter (an empty list read as "not given"): the
    library fits none (biases only) or refuses."""
    from aeroid.models import catalog
    from aeroid.pipeline.stages import StageContext
    from aeroid.pipeline.stages.library_stages import IdentifyOptions, _run_identify

    data = catalog.short_period_flight(seed=1)
    model = catalog.short_period()
    ctx = StageContext(
        IdentifyOptions(parameters=[], estimate_bias=True), {"data": data}, model=model
    )
    fit = _run_identify(ctx)
    assert dict(fit.parameters) == {} and fit.biases
    every = _run_identify(StageContext(IdentifyOptions(), {"data": data}, model=model))
    assert set(every.parameters) == set(model.parameter_names)


def test_an_unknown_model_is_named_with_its_config_file(tmp_path):
    cfg = _write(tmp_path, "model: no_such_model\nflights: [{simulated: {n_flights: 1}}]\n")
    with pytest.raises(ConfigError, match=r"camp.yaml: model 'no_such_model': expected a built-in"):
        plan(cfg)


def test_a_model_module_that_fails_on_import_is_a_config_error(tmp_path):
    (tmp_path / "broken_model.py").write_text(
        "from aeroid.models import catalog\nmodel = catalg.short_period()\n"
    )
    cfg = _write(
        tmp_path,
        "model: broken_model:model\nallow_imports: true\nflights: [{simulated: {n_flights: 1}}]\n",
    )
    with pytest.raises(ConfigError, match=r"cannot import 'broken_model' \(NameError"):
        plan(cfg)
