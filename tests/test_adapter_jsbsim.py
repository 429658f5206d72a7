"""JSBSim adapter: property mapping, deterministic resets, isolation, logs, and a recovered truth."""

from __future__ import annotations

import os
import pickle
import shutil
import socket
import sys
from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog

jsbsim = pytest.importorskip("jsbsim")

from aeroid.adapters.jsbsim import JsbsimModel, load_jsbsim_output  # noqa: E402

IC = {"ic/h-sl-ft": 5000.0, "ic/vc-kts": 120.0}
PKG = Path(jsbsim.get_default_root_dir())


def _model(**kw):
    """The spec's example: pitch trim as the parameter, elevator command as the control."""
    args = dict(
        parameters={"pitch_trim": ("fcs/pitch-trim-cmd-norm", 0.0)},
        controls={"elevator": "fcs/elevator-cmd-norm"},
        outputs={"q_rad_s": "velocities/q-rad_sec", "theta_rad": "attitude/theta-rad"},
        initial_conditions=IC,
    )
    args.update(kw)
    return JsbsimModel("c172x", **args)


@pytest.fixture(scope="module")
def model():
    return _model()


@pytest.fixture(scope="module")
def grid():
    t = np.arange(201) / 50.0  # 4 s at 50 Hz
    return t, catalog.doublet(t, start=0.5, width=0.5, amplitude=0.1)


def _snapshot(root: Path) -> dict[str, float]:
    return {
        str(p.relative_to(root)): p.stat().st_mtime
        for p in root.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }


def test_is_a_simulator_model(model):
    assert isinstance(model, aeroid.SimulatorModel)
    assert model.controls == ("elevator",)
    assert model.outputs == ("q_rad_s", "theta_rad")
    assert dict(model.parameters) == {"pitch_trim": 0.0}


def test_injected_pitch_trim_is_recovered_by_identify(model, grid):
    t, u = grid
    truth = 0.08
    data = model.simulate(t, u, None, {"pitch_trim": truth}).to_flight_data()
    result = aeroid.identify(model, data, ["pitch_trim"])
    assert result.parameters["pitch_trim"] == pytest.approx(truth, rel=2e-2)


def test_resets_are_bit_identical(model, grid):
    t, u = grid
    a = model.simulate(t, u, None, {"pitch_trim": 0.05})
    b = model.simulate(t, -u, None, {"pitch_trim": -0.1})  # something else in between
    c = model.simulate(t, u, None, {"pitch_trim": 0.05})
    assert np.array_equal(a.outputs, c.outputs)
    assert not np.array_equal(a.outputs, b.outputs)
    other = _model()  # a second instance agrees bit for bit too
    assert np.array_equal(other.simulate(t, u, None, {"pitch_trim": 0.05}).outputs, a.outputs)
    clone = pickle.loads(pickle.dumps(model))
    assert np.array_equal(clone.simulate(t, u, None, {"pitch_trim": 0.05}).outputs, a.outputs)


def test_outputs_land_exactly_on_the_grid():
    m = _model(controls={})
    t50 = np.arange(101) / 50.0  # 50 Hz: JSBSim steps at 150 Hz, every third step sampled
    t150 = np.arange(301) / 150.0
    y50 = m.simulate(t50).outputs
    y150 = m.simulate(t150).outputs
    assert np.array_equal(y50, y150[::3])
    # the clock starts at time[0]: a shifted grid gives the same trajectory
    assert np.array_equal(m.simulate(t50 + 7.25).outputs, y50)
    # a non-uniform grid is interpolated between JSBSim steps
    tn = np.sort(np.concatenate([[0.0, 2.0], np.random.default_rng(0).uniform(0, 2, 40)]))
    yn = m.simulate(tn).outputs
    ref = np.column_stack([np.interp(tn, t150, y150[:, j]) for j in range(2)])
    np.testing.assert_allclose(yn, ref, atol=2e-3)


def test_trim_starts_in_equilibrium_and_controls_are_increments():
    m = JsbsimModel(
        "c172x",
        controls={"elevator": "fcs/elevator-cmd-norm"},
        outputs={"q": "velocities/q-rad_sec", "alpha": "aero/alpha-rad"},
        initial_conditions={
            "ic/h-sl-ft": 5000.0,
            "ic/vc-kts": 100.0,
            "ic/gamma-deg": 0.0,
            "propulsion/set-running": -1,
        },
        trim="full",
    )
    t = np.arange(101) / 50.0
    still = m.simulate(t)
    assert np.max(np.abs(still.output("q"))) < 1e-4
    assert np.ptp(still.output("alpha")) < 1e-4
    kicked = m.simulate(t, np.full(t.size, 0.1))
    assert kicked.output("q").min() < -0.02  # trailing edge down: nose down


def test_simulate_data_uses_measured_controls(model, grid):
    t, u = grid
    data = model.simulate(t, u).to_flight_data()
    np.testing.assert_array_equal(model.simulate_data(data).outputs, model.simulate(t, u).outputs)
    # generic integrator options are accepted (and have no effect) ...
    same = model.simulate(t, u, method="RK45", rtol=1e-9, atol=1e-12, substeps=4)
    np.testing.assert_array_equal(same.outputs, model.simulate(t, u).outputs)
    # ... anything else is refused with the valid list
    with pytest.raises(aeroid.AdapterError, match="valid options"):
        model.simulate(t, u, speed="fast")


def test_no_files_in_the_package_and_no_sockets(tmp_path):
    before = _snapshot(PKG)
    m = _model()
    m.simulate(np.linspace(0.0, 1.0, 51))
    m.executive().run_ic()
    assert _snapshot(PKG) == before
    assert not (PKG / "JSBout172B.csv").exists()  # c172x declares this CSV log

    # An aircraft that declares a socket output to a listener we own: nothing connects.
    root = tmp_path / "root"
    (root / "aircraft").mkdir(parents=True)
    for d in ("engine", "systems"):
        os.symlink(PKG / d, root / d)
    shutil.copytree(PKG / "aircraft" / "c172x", root / "aircraft" / "c172x")
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.setblocking(False)
    port = srv.getsockname()[1]
    xml = root / "aircraft" / "c172x" / "c172x.xml"
    xml.write_text(
        xml.read_text().replace(
            "</fdm_config>",
            f'<output name="127.0.0.1" type="SOCKET" port="{port}" rate="20">'
            "<rates>ON</rates></output></fdm_config>",
        )
    )
    try:
        JsbsimModel("c172x", outputs={"q": "velocities/q-rad_sec"}, root=root).simulate(
            np.linspace(0.0, 1.0, 11)
        )
        with pytest.raises(BlockingIOError):
            srv.accept()
    finally:
        srv.close()
    assert sorted(p.name for p in root.iterdir()) == ["aircraft", "engine", "systems"]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"parameters": {"k": ("fcs/no-such-thing", 0.0)}}, r"parameter 'k'.*'fcs/no-such-thing'"),
        ({"controls": {"e": "fcs/elevatr-cmd-norm"}}, r"control 'e'.*similar.*elevator-cmd-norm"),
        ({"outputs": {"y": "velocities/qq"}}, r"output 'y'.*'velocities/qq'"),
        ({"initial_conditions": {"ic/h-sl-furlongs": 1.0}}, r"ic/h-sl-furlongs"),
        ({"controls": {"e": "velocities/q-rad_sec"}}, r"control 'e'.*read-only"),
        ({"parameters": {"k": "fcs/pitch-trim-cmd-norm"}}, r"\(property, nominal value\)"),
        ({"outputs": {}}, "at least one"),
        ({"trim": "sideways"}, "trim"),
        ({"dt": -1.0}, "dt"),
    ],
)
def test_bad_configuration_names_the_culprit(kwargs, match):
    with pytest.raises(aeroid.AdapterError, match=match):
        _model(**kwargs)


def test_bad_simulation_input(model):
    t = np.linspace(0.0, 1.0, 11)
    with pytest.raises(aeroid.AdapterError, match="ic/nonsense"):
        model.simulate(t, None, {"ic/nonsense": 1.0})
    with pytest.raises(aeroid.SimulationError, match="x0"):
        model.simulate(t, None, [0.0, 1.0])
    with pytest.raises(aeroid.SimulationError, match="'wing_area'"):
        model.simulate(t, None, None, {"wing_area": 1.0})
    with pytest.raises(aeroid.SimulationError, match=r"controls: expected shape \(11, 1\)"):
        model.simulate(t, np.zeros((10, 1)))
    with pytest.raises(aeroid.SimulationError, match="strictly increasing"):
        model.simulate([0.0, 1.0, 1.0])


def test_unknown_aircraft():
    with pytest.raises(aeroid.AdapterError, match=r"aircraft 'c999'.*c172x"):
        JsbsimModel("c999", outputs={"q": "velocities/q-rad_sec"})


def test_missing_jsbsim_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "jsbsim", None)
    with pytest.raises(aeroid.AdapterError, match=r'pip install "aeroid\[jsbsim\]"'):
        JsbsimModel("c172x", outputs={"q": "velocities/q-rad_sec"})


def test_load_jsbsim_output_reads_a_real_log(tmp_path, model):
    fdm = model.executive()
    directive = tmp_path / "log.xml"
    directive.write_text(
        '<output name="flight.csv" type="CSV" rate="20"><rates>ON</rates>'
        '<property caption="alpha_rad">aero/alpha-rad</property></output>'
    )
    fdm.set_output_path(str(tmp_path))
    assert fdm.set_output_directive(str(directive))
    fdm.enable_output()
    for k, v in IC.items():
        fdm.set_property_value(k, v)
    fdm.run_ic()
    q = []
    for _ in range(240):  # 2 s at 120 Hz; the log samples every 6th step
        fdm.run()
        q.append(fdm.get_property_value("velocities/q-rad_sec"))
    del fdm
    data = load_jsbsim_output(tmp_path / "flight.csv")
    assert "Q (deg/s)" in data and "alpha_rad" in data  # headers verbatim
    assert data.units["Q (deg/s)"] == "deg/s"
    np.testing.assert_allclose(data.time, np.arange(41) * 0.05, atol=1e-9)
    np.testing.assert_allclose(data["Q (deg/s)"][1:], np.degrees(q[5::6]), rtol=1e-9, atol=1e-9)
    assert data.metadata["format"] == "jsbsim"


def test_load_jsbsim_output_repeated_and_backward_time(tmp_path):
    good = tmp_path / "a.csv"
    good.write_text("Time,Q (deg/s),h\n0,0.5,1\n0,1.5,2\n0.1,2.5,3\n0.2,3.5,4\n")
    data = load_jsbsim_output(good)
    np.testing.assert_array_equal(data.time, [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(data["Q (deg/s)"], [1.5, 2.5, 3.5])  # later row wins
    assert "h" not in data.units
    tab = tmp_path / "b.txt"
    tab.write_text("Time\tQ (deg/s)\n0\t1\n0.5\t2\n1\t3\n")
    assert load_jsbsim_output(tab).names == ("Q (deg/s)",)
    back = tmp_path / "c.csv"
    back.write_text("Time,q\n0,1\n0.1,2\n0.0,3\n0.1,4\n")
    with pytest.raises(aeroid.DataFormatError, match=r"backwards.*row 4"):
        load_jsbsim_output(back)
    bad = tmp_path / "d.csv"
    bad.write_text("Time,q\n0,1\n0.1,x\n0.2,3\n")
    with pytest.raises(aeroid.DataFormatError, match=r"row 3, column 'q'"):
        load_jsbsim_output(bad)
    with pytest.raises(aeroid.DataFormatError, match="Time"):
        notime = tmp_path / "e.csv"
        notime.write_text("t,q\n0,1\n1,2\n2,3\n")
        load_jsbsim_output(notime)
    with pytest.raises(aeroid.DataFormatError, match="no such file"):
        load_jsbsim_output(tmp_path / "missing.csv")


@pytest.mark.parametrize("rate", [120.0, 400.0])
def test_the_flight_controls_keep_their_rate_limit_at_any_sample_rate(rate):
    # the c172x's aileron actuator is rate-limited to 1.57 rad/s; a step command moves it
    # at that rate whatever step JSBSim takes (set before the aircraft loads: set after,
    # the actuator kept 1/120 s and moved 5.2 rad/s on a 400 Hz grid)
    m = JsbsimModel(
        "c172x",
        controls={"aileron": "fcs/aileron-cmd-norm"},
        outputs={"left": "fcs/left-aileron-pos-rad"},
        initial_conditions=IC,
    )
    t = np.arange(int(rate) // 2) / rate
    y = m.simulate(t, np.where(t >= 0.1, 1.0, 0.0)[:, None]).output("left")
    assert np.max(np.abs(np.diff(y))) * rate == pytest.approx(1.57, rel=1e-6)


def test_controls_that_are_not_numbers_are_named(model, grid):
    t, _ = grid
    with pytest.raises(aeroid.errors.SimulationError, match="control 'elevator': expected numbers"):
        model.simulate(t, {"elevator": ["up"] * t.size})
    with pytest.raises(aeroid.errors.SimulationError, match="controls: complex"):
        model.simulate(t, np.full(t.size, 1j))
