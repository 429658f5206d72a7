"""Checks of a whole campaign before its first task: every mistake listed in one error."""

from __future__ import annotations

import contextlib
import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import ConfigError
from aeroid.pipeline import load_config, resolve_model, resolve_pipeline
from aeroid.pipeline.plans.checks import check_campaign, preflight

ROOT = Path(__file__).resolve().parents[1]
SIM = "flights: [{simulated: {n_flights: 2}}]\n"
HEADER = "time,alpha,q,elevator"


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


def _config(tmp: Path, text: str, *, model: str = "short_period") -> Path:
    p = tmp / "camp.yaml"
    p.write_text(f"model: {model}\n{text}")
    return p


def _csv(path: Path, header: str = HEADER, rows: int = 3) -> Path:
    n = len(header.split(","))
    body = "".join(",".join([f"{0.1 * i}"] + ["0"] * (n - 1)) + "\n" for i in range(rows))
    path.write_text(header + "\n" + body)
    return path


def _refused(cfg: Path, pattern: str) -> str:
    """Run the pre-flight check (with a hang guard) and return its error's text."""
    with _deadline(30.0), pytest.raises(ConfigError, match=pattern) as err:
        preflight(cfg)
    return str(err.value)


# -- names in stage options -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("stages", "expected"),
    [
        (
            "identify: {parameters: [Z_alpha, M_qq]}",
            r"camp.yaml: stages.identify.parameters: 'M_qq' is not a parameter of model "
            r"'short_period'; did you mean 'M_q'\?",
        ),
        (
            "identify: {bounds: {M_dleta: [null, 0.0]}}",
            r"stages.identify.bounds: 'M_dleta' is not a parameter .*did you mean 'M_delta'\?",
        ),
        (
            "identify: {x0: {alpah: 0.0}}",
            r"stages.identify.x0: 'alpah' is not a state .*did you mean 'alpha'\?",
        ),
        (
            "identify: {weights: {qq: 1.0}}",
            r"stages.identify.weights: 'qq' is not an output .*did you mean 'q'\?",
        ),
        (
            "infer: {priors: {Z_alfa: {normal: [0.0, 1.0]}}}",
            r"stages.infer.priors: 'Z_alfa' is not a parameter .*did you mean 'Z_alpha'",
        ),
        (
            "filter: {process_noise: {alpha: 1.0e-8, qq: 1.0e-8}, "
            "measurement_noise: {alpha: 1.0e-4, q: 1.0e-4}}",
            r"stages.filter.process_noise: 'qq' is not a state .*did you mean 'q'\?",
        ),
        (
            "design: {maneuver: {type: doublet, control: elevatr, options: {amplitude: 0.05}}, "
            "parameters: [M_q]}",
            r"stages.design.maneuver.control: 'elevatr' is not a control .*'elevator'\?",
        ),
        (
            "sensitivities: {parameters: [Mq]}",
            r"stages.sensitivities.parameters: 'Mq' is not a parameter .*did you mean 'M_q'\?",
        ),
        (
            "frequency: {inputs: [aileron]}",
            r"stages.frequency.inputs: 'aileron' is not a control .*its controls: elevator",
        ),
        (
            "frequency_identify: {parameters: [M_qq]}",
            r"stages.frequency_identify.parameters: 'M_qq' is not a parameter .*'M_q'\?",
        ),
        (
            "frequency_identify: {outputs: [qq]}",
            r"stages.frequency_identify.outputs: 'qq' is not an output .*did you mean 'q'\?",
        ),
    ],
)
def test_a_name_the_model_lacks_is_named_with_a_suggestion(tmp_path, stages, expected):
    _refused(_config(tmp_path, SIM + f"stages:\n  {stages}\n"), expected)


def test_a_metric_typo_is_named_with_a_suggestion(tmp_path):
    cfg = _config(tmp_path, SIM + "stages: {propagate: {metric: natural_frequncy}}\n")
    _refused(
        cfg,
        r"stages.propagate.metric: unknown metric 'natural_frequncy'; did you mean "
        r"'natural_frequency'\?",
    )


def test_an_imported_metric_needs_allow_imports_and_must_exist(tmp_path):
    cfg = _config(tmp_path, SIM + "stages: {propagate: {metric: 'math:sqrt'}}\n")
    _refused(
        cfg,
        r"stages.propagate.metric: 'math:sqrt' runs Python code from the installed module "
        r"'math': allow it with `allow_imports: true`",
    )
    cfg.write_text(cfg.read_text() + "allow_imports: true\n")
    preflight(cfg)  # allowed and importable
    cfg.write_text(cfg.read_text().replace("math:sqrt", "math:sqrtt"))
    _refused(cfg, r"stages.propagate.metric: metric 'math:sqrtt': 'math' has no attribute")


def test_a_builtin_metric_reading_a_parameter_the_model_lacks(tmp_path):
    (tmp_path / "a.csv").write_text("time,u,y\n0,0,0\n0.1,0,0\n0.2,0,0\n")
    cfg = _config(tmp_path, "flights: [a.csv]\nstages: {propagate: {}}\n", model="first_order")
    _refused(
        cfg,
        r"stages.propagate.metric: natural_frequency reads the parameter 'M_q', "
        r"which model 'first_order' lacks",
    )


def test_a_generator_typo_is_named_with_a_suggestion(tmp_path):
    cfg = _config(tmp_path, "flights: [{simulated: {generator: short_period_campain}}]\n")
    _refused(
        cfg,
        r"flights\[0\].simulated.generator: Input should be 'short_period_campaign' "
        r"\(got 'short_period_campain'\); did you mean 'short_period_campaign'\?",
    )


def test_a_simulated_flight_without_the_models_channels(tmp_path):
    (tmp_path / "lag.py").write_text(
        "import numpy as np\nfrom aeroid import Model\n"
        "MODEL = Model(['y'], ['u'], {'k': 1.0}, "
        "lambda t, x, u, p: np.array([-p['k'] * x[0] + u[0]]), name='lag')\n"
    )
    cfg = _config(tmp_path, SIM, model="lag:MODEL")
    _refused(
        cfg,
        r"model: 'lag:MODEL' runs Python code from .*lag.py: allow it with `allow_imports: true`",
    )
    # allowed by the caller (the command line's --allow-imports) or by the config
    with pytest.raises(ConfigError) as by_caller:
        preflight(cfg, allow_imports=True)
    cfg.write_text(cfg.read_text() + "allow_imports: true\n")
    text = _refused(
        cfg, r"flights\[0\].simulated: model 'lag' needs the control 'u', which the flight lacks"
    )
    assert "none of model 'lag''s outputs (y); its channels: alpha, elevator, q" in text
    assert str(by_caller.value) == text


# -- flight files -----------------------------------------------------------------------------


def test_a_missing_flight_file_is_named_with_a_suggestion(tmp_path):
    _csv(tmp_path / "flight_01.csv")
    cfg = _config(tmp_path, "flights: [flight_1.csv, 'nothing/*.csv']\n")
    text = _refused(
        cfg, r"flights\[0\]: no such file: .*flight_1.csv; did you mean 'flight_01.csv'\?"
    )
    assert "flights[1]: the pattern 'nothing/*.csv' matches no file" in text


def test_dev_zero_as_a_flight_is_refused_without_reading_it(tmp_path):
    cfg = _config(tmp_path, "flights: [/dev/zero]\n")
    _refused(cfg, r"camp.yaml: flights\[0\]: /dev/zero is a device, not a flight file")


def test_a_fifo_as_a_flight_is_refused_without_opening_it(tmp_path):
    os.mkfifo(tmp_path / "pipe.csv")  # opening it to read would wait for a writer forever
    cfg = _config(tmp_path, "flights: ['*.csv']\n")
    _refused(cfg, r"flights\[0\]: .*pipe.csv is a FIFO \(named pipe\), not a flight file")


def test_a_directory_as_a_flight_is_refused(tmp_path):
    (tmp_path / "flights.csv").mkdir()
    cfg = _config(tmp_path, "flights: [{path: flights.csv, time_column: time}]\n")
    _refused(cfg, r"flights\[0\].path: .*flights.csv is a directory, not a flight file")


def test_a_channel_missing_from_a_csv_header(tmp_path):
    _csv(tmp_path / "a.csv", "time,alpha,q,elev")
    text = _refused(
        _config(tmp_path, "flights: [a.csv]\n"),
        r"flights\[0\]: a.csv: model 'short_period' needs the control 'elevator', which the "
        r"flight lacks; did you mean 'elev'\?",
    )
    assert text.count("\n") == 0  # alpha and q are there: one problem


def test_only_the_header_is_read(tmp_path):
    # a body that `load_flight_test` refuses (and a long one) does not slow the check:
    # the channels are all in the header
    p = tmp_path / "a.csv"
    p.write_text("# exported by the flight-test rig\n" + HEADER + "\n" + "x,y,z,w\n" * 50000)
    preflight(_config(tmp_path, "flights: [a.csv]\n"))


def test_a_channel_missing_from_a_parquet_schema(tmp_path):
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    t = np.arange(5) * 0.1
    table = pa.table({"time": t, "alpha": t, "elevator": t})
    pq.write_table(table, tmp_path / "a.parquet")
    cfg = _config(
        tmp_path, "flights: [a.parquet]\nstages: {infer: {priors: {M_q: {normal: [-2.0, 2.0]}}}}\n"
    )
    # the fit would use alpha alone, but inference fits every output
    _refused(cfg, r"a.parquet: model 'short_period' needs the output 'q', which the flight lacks")
    (tmp_path / "a.parquet").write_bytes(b"PAR1 not really")
    _refused(cfg, r"flights\[0\]: .*a.parquet: not a readable Parquet file")


def test_a_channel_missing_from_a_matlab_file(tmp_path):
    from scipy.io import savemat

    t = np.arange(5) * 0.1
    savemat(tmp_path / "a.mat", {"time": t, "alpha": t, "q": t, "cmd": np.c_[t, t], "k": 1.0})
    cfg = _config(tmp_path, "flights: [a.mat]\n")
    _refused(
        cfg,
        r"a.mat: model 'short_period' needs the control 'elevator', .*its channels: "
        r"alpha, cmd_0, cmd_1, q",
    )
    # the loader's column mapping is followed: cmd_0 renamed to elevator is the control
    cfg.write_text(
        cfg.read_text().replace(
            "[a.mat]", "[{path: a.mat, channels: {alpha: alpha, q: q, cmd_0: elevator}}]"
        )
    )
    preflight(cfg)


def test_a_plain_map_in_a_config_reads_the_way_round_the_file_decides(tmp_path):
    # {model_name: column}, as ChannelMap and the README's channel maps read it, and
    # {column: model_name}, as load_flight_test reads a table's: both plan, and load
    _csv(tmp_path / "r.csv", "time,de,aoa,qq")
    for m in ("{elevator: de, alpha: aoa, q: qq}", "{de: elevator, aoa: alpha, qq: q}"):
        cfg = _config(tmp_path, f"flights: [{{path: r.csv, channels: {m}}}]\n")
        preflight(cfg)
    # a cycle of the file's own columns reads both ways: refused before anything runs
    cfg = _config(tmp_path, "flights: [{path: r.csv, channels: {de: aoa, aoa: qq, qq: de}}]\n")
    _refused(cfg, r"r.csv: channels: the map \{de: aoa, aoa: qq, qq: de\} names .* both sides")


def test_a_channel_missing_from_a_flight_log(tmp_path):
    h5py = pytest.importorskip("h5py")
    t = np.arange(50) / 50.0
    with h5py.File(tmp_path / "flight.h5", "w") as f:
        for name in ("time", "alpha", "q", "de"):
            f[name] = t
    cfg = _config(tmp_path, "flights: [flight.h5]\n")
    _refused(cfg, r"flight.h5: model 'short_period' needs the control 'elevator', .*its channels: ")
    # a log's channels are picked as the loader picks them: {name: log channel}
    cfg.write_text(
        cfg.read_text().replace(
            "[flight.h5]", "[{path: flight.h5, channels: {alpha: alpha, q: q, elevator: de}}]"
        )
    )
    preflight(cfg)
    cfg.write_text(cfg.read_text().replace("elevator: de}", "elevator: dee}"))
    _refused(cfg, r"channels: log channel 'dee' not found; did you mean 'de'\?")


def test_the_loader_options_are_checked_against_the_header(tmp_path):
    _csv(tmp_path / "a.csv", "t_sec,alpha,q,elevator")
    cfg = _config(
        tmp_path,
        "flights: [{path: a.csv, time_column: tsec, channels: [alpha, q, elevator, beta]}]\n",
    )
    text = _refused(
        cfg, r"flights\[0\].path: a.csv: time column 'tsec' not found; did you mean 't_sec'\?"
    )
    assert "channels: column 'beta' not found" in text


# -- the config file itself ------------------------------------------------------------------


def test_a_yaml_alias_bomb_is_refused_fast(tmp_path):
    lines = ["      a: &a [x, x, x, x, x, x, x, x, x]"]
    for i in range(7):
        prev, cur = chr(97 + i), chr(98 + i)
        lines.append(f"      {cur}: &{cur} [" + ", ".join([f"*{prev}"] * 9) + "]")
    cfg = _config(
        tmp_path, SIM + "stages:\n  identify:\n    simulate_options:\n" + "\n".join(lines) + "\n"
    )
    with _deadline(5.0):
        _refused(cfg, r"camp.yaml: line 6, column 10: YAML anchors and aliases .*not accepted")


# -- whole campaigns ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["demo.yaml", "short_period.yaml"])
def test_the_demo_configs_pass(name):
    preflight(ROOT / "configs" / name)
    cfg = load_config(ROOT / "configs" / name)
    pipeline, _ = resolve_pipeline(cfg.pipeline, cfg.base_dir)
    check_campaign(cfg, resolve_model(cfg.model), pipeline, base_dir=cfg.base_dir)
    preflight(cfg, pipeline=pipeline)


def test_several_mistakes_are_all_listed_in_one_error(tmp_path):
    _csv(tmp_path / "a.csv", "time,alpha,elevator")
    (tmp_path / "dir.csv").mkdir()
    cfg = _config(
        tmp_path,
        "flights: [a.csv, missing.csv, dir.csv, {simulated: {n_flights: 2}}]\n"
        "stages:\n"
        "  identfy: {}\n"
        "  identify: {parameters: [M_qq], max_iterations: 0}\n"
        "  propagate: {metric: damping}\n"
        "  infer: {parameters: {Z_alfa: {normal: [0.0, 1.0]}}}\n",
    )
    text = _refused(cfg, "identfy")
    lines = text.splitlines()
    assert all(line.startswith(f"{cfg}: ") for line in lines)
    expected = [
        r"stages.identfy: unknown stage; pipeline 'campaign' has .*; did you mean 'identify'\?",
        r"stages.identify.max_iterations: Input should be greater than or equal to 1",
        r"stages.propagate.metric: unknown metric 'damping'; did you mean 'damping_ratio'\?",
        r"stages.infer.parameters: 'Z_alfa' is not a parameter",
        r"flights\[0\]: a.csv: model 'short_period' needs the output 'q'",
        r"flights\[1\]: no such file: .*missing.csv",
        r"flights\[2\]: .*dir.csv is a directory",
    ]
    for pattern in expected:
        assert sum(bool(re.search(pattern, line)) for line in lines) == 1, pattern
    # the options that did not validate are reported, not checked for names
    assert len(lines) == len(expected)


def test_without_a_model_or_pipeline_those_checks_are_skipped(tmp_path):
    cfg = load_config(
        _config(tmp_path, "flights: [/dev/null]\nstages: {identify: {parameters: [nothing]}}\n")
    )
    with pytest.raises(ConfigError) as err:
        check_campaign(cfg, None, None, base_dir=tmp_path)
    # the file fault is found; the parameter name is not checked against a model
    assert str(err.value).splitlines() == [
        f"{cfg.source}: flights[0]: /dev/null is a device, not a flight file"
    ]
    cfg = load_config(_config(tmp_path, SIM + "stages: {identify: {parameters: [M_qq]}}\n"))
    check_campaign(cfg, None, None)
    with pytest.raises(ConfigError, match="'M_qq' is not a parameter"):
        check_campaign(cfg, resolve_model("short_period"), None)


class _Simulator:
    """What the engine sees of an external simulator: names, no states (no `Model`)."""

    def __init__(self) -> None:
        self.name = "c172"
        self.controls = ("delta_e",)
        self.outputs = ("alpha", "q")
        self.parameters = {"Cm_alpha": -0.9, "Cm_q": -12.0}


def test_an_external_simulator_is_checked_by_the_names_it_has(tmp_path):
    _csv(tmp_path / "a.csv", "time,alpha,q,delta_e")
    cfg = load_config(
        _config(
            tmp_path,
            "flights: [a.csv]\nstages:\n"
            "  identify: {parameters: [Cm_alfa], x0: {anything: 0.0}, weights: {qq: 1.0}}\n",
        )
    )
    pipeline, _ = resolve_pipeline(cfg.pipeline, cfg.base_dir)
    with pytest.raises(ConfigError) as err:
        check_campaign(cfg, _Simulator(), pipeline)
    lines = str(err.value).splitlines()
    # no named states: x0 cannot be checked; the rest is
    assert [line.split(": ", 1)[1] for line in lines] == [
        "stages.identify.parameters: 'Cm_alfa' is not a parameter of model 'c172'; "
        "did you mean 'Cm_alpha'?",
        "stages.identify.weights: 'qq' is not an output of model 'c172'; did you mean 'q'?",
    ]


# -- option values the library would refuse, found before any flight runs ---------------------


@pytest.mark.parametrize(
    ("stages", "expected"),
    [
        (
            "identify: {simulate_options: {method: rk5}}",
            r"stages.identify.simulate_options\['method'\]: unknown method 'rk5'",
        ),
        (
            "identify: {simulate_options: {substeps: -2}}",
            r"stages.identify.simulate_options\['substeps'\]",
        ),
        (
            "identify: {simulate_options: {atol: -1}}",
            r"stages.identify.simulate_options\['atol'\]: expected a finite non-negative",
        ),
        (
            "identify: {simulate_options: {control_interpolation: cubc}}",
            r"stages.identify.simulate_options\['control_interpolation'\]: 'cubc' is unknown",
        ),
        (
            "identify: {simulate_options: {control_interpolation: {elevatr: cubic}}}",
            r"stages.identify.simulate_options\['control_interpolation'\]: \['elevatr'\] are "
            r"not controls",
        ),
        (
            "validate: {simulate_options: {rtol: abc}}",
            r"stages.validate.simulate_options\['rtol'\]: expected a finite positive number, "
            r"got 'abc'",
        ),
        (
            "infer: {priors: {M_q: {normal: [-1.0, 1.0]}}, simulate_options: {rtol: 0}}",
            r"stages.infer.simulate_options\['rtol'\]: expected a finite positive number",
        ),
        ("identify: {gradient: jaxx}", r"stages.identify.gradient: .*'jax'"),
        ("identify: {error_bars: sandwhich}", r"stages.identify.error_bars: .*'white'"),
    ],
)
def test_an_option_value_the_library_refuses_is_named_before_any_run(tmp_path, stages, expected):
    _refused(_config(tmp_path, SIM + f"stages:\n  {stages}\n"), expected)


def test_good_simulate_options_pass_the_check(tmp_path):
    stages = (
        "identify: {simulate_options: {method: RK45, rtol: 1.0e-8, atol: 0, "
        "control_interpolation: {elevator: cubic}}, gradient: fd, error_bars: white}"
    )
    preflight(_config(tmp_path, SIM + f"stages:\n  {stages}\n"))


# -- end to end: the command refuses before any task ---------------------------------------------


@pytest.mark.parametrize(
    ("flights", "stages", "expected"),
    [
        ("[a.csv]", "identify: {parameters: [M_qq]}", r"'M_qq' is not a parameter"),
        ("[a.csv]", "propagate: {metric: dampingratio}", r"did you mean 'damping_ratio'\?"),
        ("[/dev/zero]", "{}", r"/dev/zero is a device, not a flight file"),
        ("[pipe.csv]", "{}", r"pipe.csv is a FIFO \(named pipe\)"),
        ("[b.csv]", "{}", r"needs the control 'elevator', which the flight lacks"),
        ("[a.csv]", "identify: {simulate_options: {method: rk5}}", r"\['method'\]: unknown"),
    ],
)
@pytest.mark.parametrize("command", ["run", "status"])
def test_the_command_refuses_each_mistake_before_any_task(
    tmp_path, command, flights, stages, expected
):
    from click.testing import CliRunner

    from aeroid.cli import main

    _csv(tmp_path / "a.csv")
    _csv(tmp_path / "b.csv", "time,alpha,q")
    os.mkfifo(tmp_path / "pipe.csv")
    cfg = _config(tmp_path, f"store: store\nflights: {flights}\nstages:\n  {stages}\n")
    args = [command, str(cfg)] + (["--workers", "0"] if command == "run" else [])
    with _deadline(30.0):
        result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert re.search(expected, result.output), result.output
    assert not list((tmp_path / "store").glob("*/*"))  # nothing ran, nothing stored


# -- flight logs through a channel map -------------------------------------------------------

PX4_LOG = ROOT / "tests" / "data" / "px4" / "sample_log_small.ulg"


def test_channel_map_mistakes_of_a_log_flight_are_listed_together(tmp_path):
    pytest.importorskip("pyulog")
    cfg = _config(
        tmp_path,
        f"""flights:
  - path: {PX4_LOG}
    channels:
      y: {{channel: "vehicle_angular_velocity.xyz[0]", unit: degs}}
      u: {{channel: "actuator_controls_0.contrl[0]"}}
    sample_rate: 100
    window: [10.0, 25.0]
  - path: {PX4_LOG}
    channels: {{y: "vehicle_angular_velocity.xyz[0]"}}
    sample_rate: 100
    window: {{mode: "POSCTL"}}
  - path: {PX4_LOG}
    channels: {{y: "vehicle_angular_velocity.xyz[0]", u: "actuator_controls_0.control[0]"}}
    sample_rate: 100
    segments: {{inputs: [rudder]}}
""",
        model="first_order",
    )
    text = _refused(cfg, "no known conversion")
    lines = text.splitlines()
    assert any(
        re.search(
            r"flights\[0\]\.channels\.y\.unit: no known conversion from 'degs'; did you "
            r"mean 'deg/s' or 'deg'\? \(known units: cdeg",
            line,
        )
        for line in lines
    ), text
    assert any(
        re.search(
            r"flights\[0\]\.path: .*log channel 'actuator_controls_0.contrl\[0\]' not "
            r"found; did you mean 'actuator_controls_0.control\[0\]'",
            line,
        )
        for line in lines
    ), text
    assert any(
        re.search(
            r"flights\[0\]\.window: .*\[10, 25\] s is not inside the span \[20.3267, "
            r"26.8253\] s",
            line,
        )
        for line in lines
    ), text
    assert any(
        re.search(r"flights\[1\]\.window: .*matches no part of the log", line) for line in lines
    ), text
    assert any(
        re.search(r"flights\[2\]\.segments: .*input 'rudder' not found", line) for line in lines
    ), text


def test_the_px4_roll_campaign_passes_its_checks():
    pytest.importorskip("pyulog")
    with _deadline(30.0):
        preflight(ROOT / "configs" / "px4_roll.yaml")


def test_every_missing_flight_file_is_named_under_its_own_index(tmp_path):
    # the demo's flights each bring their own trim, so they are checked in groups
    text = (ROOT / "configs" / "demo.yaml").read_text(encoding="utf-8")
    text = text.replace("c172x/flight_01.csv", "nope1.csv").replace(
        "c172x/flight_04.csv", "nope4.csv"
    )
    text = text.replace("path: c172x/", f"path: {ROOT / 'configs' / 'c172x'}/")
    cfg = tmp_path / "demo.yaml"
    cfg.write_text(text, encoding="utf-8")
    from aeroid.pipeline import plan

    with pytest.raises(ConfigError) as info:
        plan(cfg)
    lines = str(info.value).splitlines()
    assert any("flights[0].path: no such file" in ln and "nope1.csv" in ln for ln in lines)
    assert any("flights[3].path: no such file" in ln and "nope4.csv" in ln for ln in lines)
