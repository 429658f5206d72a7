"""The JAX backend: compiled RK4 rollout, exact Jacobians, vmapped batches."""

from __future__ import annotations

import subprocess
import sys
from types import MappingProxyType

import numpy as np
import pytest

import aeroid
from aeroid.models import catalog

jnp = pytest.importorskip("jax.numpy")

from aeroid.models import jax_compiled as _jax  # noqa: E402
from aeroid.models.jax_backend import simulate_rk4  # noqa: E402


def _sp_jax(t, x, u, p):
    alpha, q = x[0], x[1]
    return jnp.array(
        [
            p["Z_alpha"] * alpha + q,
            p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0],
        ]
    )


def _sp_model(params=None):
    return aeroid.Model(
        ["alpha", "q"], ["elevator"], dict(params or catalog.SHORT_PERIOD_TRUTH), _sp_jax
    )


def _pendulum_model(xp=jnp):
    """Nonlinear, time-varying, with a measurement function (exercises every path).

    ``xp=np`` gives the numpy twin used as the fast solve_ivp reference.
    """

    def f(t, x, u, p):
        th, w = x[0], x[1]
        return xp.array([w, -p["g_l"] * xp.sin(th) - p["c"] * w + u[0] * xp.cos(0.5 * t)])

    def h(t, x, u, p):
        return xp.array([xp.sin(x[0]), x[1] ** 2 + p["c"]])

    return aeroid.Model(
        ["theta", "omega"],
        ["torque"],
        {"g_l": 9.0, "c": 0.3},
        f,
        outputs=["s", "w2"],
        measurement=h,
        name="pendulum",
    )


def _decay_model(k=0.7):
    return aeroid.Model(["x"], ["u"], {"k": k}, lambda t, x, u, p: -p["k"] * x, name="decay")


def test_simulate_rk4_matches_solve_ivp_linear(sp_clean):
    model = _sp_model()
    fast = simulate_rk4(model, sp_clean.time, sp_clean, [0.0, 0.0], substeps=8)
    # the numpy twin (same equations) keeps the tight solve_ivp reference quick
    ref = catalog.short_period(catalog.SHORT_PERIOD_TRUTH).simulate(
        sp_clean.time, sp_clean, [0.0, 0.0], method="RK45", rtol=1e-12, atol=1e-14
    )
    assert fast.state_names == ("alpha", "q")
    np.testing.assert_allclose(fast.states, ref.states, rtol=0, atol=1e-7)
    np.testing.assert_allclose(fast.outputs, ref.outputs, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(fast.controls[:, 0], sp_clean["elevator"])


def test_simulate_rk4_matches_solve_ivp_nonlinear_with_measurement():
    model = _pendulum_model()
    t = np.linspace(0.0, 4.0, 201)
    u = 0.5 * np.sin(1.3 * t)
    x0 = {"theta": 1.0, "omega": 0.0}
    p = {"c": 0.25}
    fast = simulate_rk4(model, t, u, x0, p, substeps=16)
    ref = _pendulum_model(np).simulate(t, u, x0, p, method="RK45", rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(fast.states, ref.states, rtol=0, atol=1e-7)
    np.testing.assert_allclose(fast.outputs, ref.outputs, rtol=0, atol=1e-7)
    assert fast.output_names == ("s", "w2")


def test_simulate_rk4_equals_numpy_rk4_same_substeps(sp_clean):
    """Same scheme, same nodes: the compiled rollout and the numpy RK4 agree to rounding."""
    model = _sp_model()
    fast = simulate_rk4(model, sp_clean.time, sp_clean, [0.01, 0.0], substeps=3)
    ref = model.simulate(sp_clean.time, sp_clean, [0.01, 0.0], method="rk4", substeps=3)
    np.testing.assert_allclose(fast.states, ref.states, rtol=0, atol=1e-13)


def test_jacobian_matches_analytic_sensitivity_of_decay():
    # x' = -k x, x(0) = x0  =>  x = x0 e^{-kt},  dx/dk = -t x0 e^{-kt}
    k, x0 = 0.7, 2.0
    t = np.linspace(0.0, 5.0, 101)
    y, J = _jax.outputs_and_jacobian(
        _decay_model(k), t, np.zeros((t.size, 1)), np.array([x0]), {"k": k}, ["k"], substeps=4
    )
    assert y.shape == (101, 1) and J.shape == (101, 1, 1)
    exact = -t * x0 * np.exp(-k * t)
    np.testing.assert_allclose(y[:, 0], x0 * np.exp(-k * t), rtol=1e-6)
    np.testing.assert_allclose(J[1:, 0, 0], exact[1:], rtol=1e-6)
    assert J[0, 0, 0] == 0.0


def test_simulate_rk4_is_differentiable_by_the_caller():
    """The API table's "differentiable RK4": jax.jacfwd, jax.grad, jax.vmap and jax.jit
    run through `simulate_rk4` in the parameters, the initial state and the controls."""
    import jax

    k, x0 = 0.7, 2.0
    t = np.linspace(0.0, 5.0, 101)
    model = _decay_model(k)
    u = np.zeros(t.size)

    def path(kk):
        return simulate_rk4(model, t, u, [x0], {"k": kk}).state("x")

    exact = -t * x0 * np.exp(-k * t)  # d/dk of x0 e^{-kt}
    np.testing.assert_allclose(np.asarray(jax.jacfwd(path)(k))[1:], exact[1:], rtol=1e-6)
    last = jax.grad(lambda kk: path(kk)[-1])(k)
    np.testing.assert_allclose(float(last), exact[-1], rtol=1e-6)
    d_x0 = jax.grad(lambda a: simulate_rk4(model, t, u, {"x": a}, {"k": k}).state("x")[-1])(x0)
    np.testing.assert_allclose(float(d_x0), np.exp(-k * t[-1]), rtol=1e-6)
    ks = jnp.array([0.5, 0.7, 0.9])
    batch = jax.vmap(lambda kk: path(kk)[-1])(ks)
    np.testing.assert_allclose(np.asarray(batch), x0 * np.exp(-np.asarray(ks) * 5.0), rtol=1e-6)
    np.testing.assert_allclose(
        float(jax.jit(lambda kk: path(kk)[-1])(k)), x0 * np.exp(-3.5), rtol=1e-6
    )
    # the controls: x' = -k x + u with u = c constant, x(0) = 0  =>  dx/dc = (1 - e^{-kt}) / k
    forced = aeroid.Model(["x"], ["u"], {"k": k}, lambda t, x, u, p: -p["k"] * x + u[0])

    def end(c):
        return simulate_rk4(forced, t, jnp.full((t.size, 1), c), [0.0]).state("x")[-1]

    np.testing.assert_allclose(float(jax.grad(end)(0.3)), (1 - np.exp(-3.5)) / k, rtol=1e-6)
    # outside a transformation the result is the usual read-only numpy record
    plain = simulate_rk4(model, t, u, [x0], {"k": k})
    assert isinstance(plain.states, np.ndarray) and not plain.states.flags.writeable
    np.testing.assert_array_equal(np.asarray(path(k)), plain.state("x"))


def test_traced_simulate_rk4_names_bad_arguments():
    import jax

    t = np.linspace(0.0, 1.0, 11)
    model = _decay_model()
    u = np.zeros((t.size, 1))
    with pytest.raises(aeroid.SimulationError, match="'bogus'"):
        jax.grad(lambda k: simulate_rk4(model, t, u, [1.0], {"k": k, "bogus": 1.0}).state("x")[-1])(
            0.5
        )
    with pytest.raises(aeroid.SimulationError, match="x0"):
        jax.grad(lambda a: simulate_rk4(model, t, u, [a, a]).state("x")[-1])(1.0)
    with pytest.raises(aeroid.ChannelError, match="shape"):
        jax.grad(lambda c: simulate_rk4(model, t, jnp.full((3, 1), c), [1.0]).state("x")[-1])(1.0)
    with pytest.raises(aeroid.AdapterError, match="substeps"):
        jax.grad(lambda k: simulate_rk4(model, t, u, [1.0], {"k": k}, substeps=0).state("x")[-1])(
            0.5
        )


def test_jacobian_agrees_with_central_differences(sp_clean):
    model = _sp_model()
    p = dict(catalog.SHORT_PERIOD_TRUTH)
    u = sp_clean.array(["elevator"])
    names = ["M_delta", "Z_alpha"]  # a subset, in a non-declaration order
    y, J = _jax.outputs_and_jacobian(model, sp_clean.time, u, np.zeros(2), p, names, substeps=2)
    for j, n in enumerate(names):
        h = 1e-6 * abs(p[n])
        hi = _jax.batch_outputs(
            model, sp_clean.time, u, np.zeros(2), {n: [p[n] + h, p[n] - h]}, substeps=2
        )
        fd = (hi[0] - hi[1]) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], fd, rtol=0, atol=1e-6 * np.abs(fd).max())
    base = simulate_rk4(model, sp_clean.time, u, np.zeros(2), p, substeps=2)
    np.testing.assert_array_equal(y, base.outputs)


def test_batch_outputs_matches_single_rollouts():
    model = _pendulum_model()
    t = np.linspace(0.0, 2.0, 51)
    u = np.cos(t)[:, None]
    gl = np.array([8.0, 9.0, 10.0])
    ys = _jax.batch_outputs(model, t, u, np.array([0.3, 0.0]), {"g_l": gl}, substeps=4)
    assert ys.shape == (3, 51, 2)
    arr = _jax.batch_outputs(
        model, t, u, np.array([0.3, 0.0]), np.column_stack([gl, np.full(3, 0.3)]), substeps=4
    )
    np.testing.assert_array_equal(ys, arr)
    for b, g in enumerate(gl):
        one = simulate_rk4(model, t, u, [0.3, 0.0], {"g_l": g}, substeps=4)
        np.testing.assert_allclose(ys[b], one.outputs, rtol=0, atol=1e-14)


def test_compiled_functions_are_cached_per_model_and_substeps(sp_clean):
    model = _sp_model()
    simulate_rk4(model, sp_clean.time, sp_clean, substeps=2)
    fn = _jax._CACHE[model][("rollout", 2)]
    simulate_rk4(model, sp_clean.time, sp_clean, None, {"M_q": -3.0}, substeps=2)
    assert _jax._CACHE[model][("rollout", 2)] is fn
    assert fn._cache_size() == 1  # same grid shape: no retrace


def test_auto_substeps_follow_stiffness():
    fast = aeroid.Model(["x"], [], {"k": 401.0}, lambda t, x, u, p: -p["k"] * x, name="stiff")
    # h = 0.01, h*k = 4.01; a real mode takes substeps of z <= (120 * 1e-5)^(1/4) = 0.186:
    # 22 of them, and the error stays within 1e-5 of the initial amplitude
    t = np.linspace(0.0, 0.1, 11)
    y, _ = _jax.outputs_and_jacobian(
        fast, t, np.zeros((11, 0)), np.array([1.0]), {"k": 401.0}, ["k"]
    )
    assert _jax._CACHE[fast][("substeps", 11, 0.01)] == 22
    np.testing.assert_allclose(y[:, 0], np.exp(-401.0 * t), rtol=0, atol=1e-5)
    assert np.max(np.abs(y[:, 0] - np.exp(-401.0 * t))) > 1e-7  # not a far finer step


def test_divergence_raises_simulation_error():
    model = _decay_model()
    with pytest.raises(aeroid.SimulationError, match="non-finite at t ="):
        simulate_rk4(
            model, np.linspace(0, 100, 101), np.zeros((101, 1)), [1.0], {"k": -300.0}, substeps=1
        )


def test_numpy_only_dynamics_are_rejected_clearly(sp_clean):
    model = catalog.short_period()  # builds its derivative with np.array
    with pytest.raises(aeroid.AdapterError, match=r"jax\.numpy"):
        simulate_rk4(model, sp_clean.time, sp_clean)


def test_simulator_models_are_rejected():
    class Stepped:
        name = "blackbox"
        controls = ("u",)
        outputs = ("y",)
        parameters = MappingProxyType({"a": 1.0})

        def simulate(self, time, controls=None, x0=None, parameters=None, **options):
            raise NotImplementedError

        def simulate_data(self, data, *, x0=None, parameters=None, **options):
            raise NotImplementedError

    assert isinstance(Stepped(), aeroid.SimulatorModel)
    with pytest.raises(aeroid.AdapterError, match="continuous dynamics callable"):
        simulate_rk4(Stepped(), [0.0, 1.0])
    with pytest.raises(aeroid.AdapterError, match="blackbox"):
        _jax.outputs_and_jacobian(Stepped(), [0.0, 1.0], np.zeros((2, 1)), np.zeros(0), {}, ["a"])
    with pytest.raises(aeroid.AdapterError, match="stepped simulator"):
        _jax.batch_outputs(Stepped(), [0.0, 1.0], np.zeros((2, 1)), np.zeros(0), {"a": [1.0]})


def test_bad_arguments_raise_named_errors():
    model = _decay_model()
    t = np.linspace(0, 1, 5)
    with pytest.raises(aeroid.AdapterError, match="substeps"):
        simulate_rk4(model, t, np.zeros((5, 1)), [1.0], substeps=0)
    with pytest.raises(aeroid.AdapterError, match="'nope'"):
        _jax.outputs_and_jacobian(model, t, np.zeros((5, 1)), np.ones(1), {"k": 1.0}, ["nope"])
    with pytest.raises(aeroid.AdapterError, match=r"\(B, 1\)"):
        _jax.batch_outputs(model, t, np.zeros((5, 1)), np.ones(1), np.ones(3))
    with pytest.raises(aeroid.AdapterError, match="differ in length"):
        _jax.batch_outputs(
            _pendulum_model(), t, np.zeros((5, 1)), np.ones(2), {"g_l": [1, 2], "c": [1, 2, 3]}
        )
    with pytest.raises(aeroid.SimulationError, match="'zzz'"):
        simulate_rk4(model, t, np.zeros((5, 1)), [1.0], {"zzz": 1.0})
    with pytest.raises(aeroid.SimulationError, match="time"):
        simulate_rk4(model, [0.0, 0.0, 1.0], np.zeros((3, 1)), [1.0])


def test_missing_jax_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "jax", None)
    with pytest.raises(aeroid.AdapterError, match=r'pip install "aeroid\[jax\]"'):
        _jax.require_jax()


def test_importing_aeroid_does_not_import_jax():
    code = (
        "import sys, aeroid; aeroid.simulate_rk4; "
        "bad = [m for m in ('jax', 'jsbsim', 'rocketpy', 'aerosandbox') if m in sys.modules]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_dynamics_written_with_jax_numpy_run_in_float64_whatever_ran_first():
    # a fresh process: JAX starts with 32-bit floats; building the Model switches 64-bit on,
    # so the numpy paths give the same numbers before and after any JAX path has run
    code = """
import jax, jax.numpy as jnp, numpy as np
import aeroid
from aeroid.models import catalog
assert not jax.config.read("jax_enable_x64")
def f(t, x, u, p):
    return jnp.array([p["Z_alpha"] * x[0] + x[1], p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["M_delta"] * u[0]])
ref = catalog.short_period()
m = aeroid.Model(states=["alpha", "q"], controls=["elevator"], parameters=dict(ref.parameters), dynamics=f)
assert jax.config.read("jax_enable_x64")
data = catalog.short_period_flight(seed=0, duration=4.0)
a = m.simulate(data.time, data.array(["elevator"]), method="RK45", rtol=1e-10, atol=1e-12)
b = ref.simulate(data.time, data.array(["elevator"]), method="RK45", rtol=1e-10, atol=1e-12)
print(float(np.max(np.abs(a.outputs - b.outputs))))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    # float32 dynamics differ by ~6e-10 here (alpha ~1e-2 times float32's 1e-7)
    assert float(out.stdout.strip().splitlines()[-1]) < 1e-13


class _Config:
    """The two settings `_jax._persistent_cache` reads, as jax.config holds them."""

    def __init__(self, cache_dir: str | None = None) -> None:
        self.jax_compilation_cache_dir = cache_dir
        self.jax_compilation_cache_max_size = -1

    def update(self, name: str, value: object) -> None:
        setattr(self, name, value)


def _fake_jax(cache_dir: str | None = None):
    from types import SimpleNamespace

    return SimpleNamespace(config=_Config(cache_dir))


def test_persistent_cache_policy(tmp_path, monkeypatch):
    import os

    chosen = tmp_path / "mine"
    monkeypatch.setenv(_jax.CACHE_ENV, str(chosen))
    fake = _fake_jax()
    _jax._persistent_cache(fake)
    assert fake.config.jax_compilation_cache_dir == str(chosen)
    assert chosen.is_dir() and (chosen.stat().st_mode & 0o777) == 0o700
    # the user's own JAX setting wins
    fake = _fake_jax("/somewhere/else")
    _jax._persistent_cache(fake)
    assert fake.config.jax_compilation_cache_dir == "/somewhere/else"
    # switched off
    monkeypatch.setenv(_jax.CACHE_ENV, "off")
    fake = _fake_jax()
    _jax._persistent_cache(fake)
    assert fake.config.jax_compilation_cache_dir is None
    # a folder others may write to holds code JAX would run: refused
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    monkeypatch.setenv(_jax.CACHE_ENV, str(shared))
    fake = _fake_jax()
    _jax._persistent_cache(fake)
    assert fake.config.jax_compilation_cache_dir is None
    # the default: per user, per CPU kind, under the cache home
    monkeypatch.delenv(_jax.CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home"))
    fake = _fake_jax()
    _jax._persistent_cache(fake)
    folder = fake.config.jax_compilation_cache_dir
    assert folder is not None and folder.startswith(str(tmp_path / "home" / "aeroid" / "jax-"))
    # programs that compile in a fifth of a second are kept too, unless the user says
    assert fake.config.jax_persistent_cache_min_compile_time_secs == 0.2
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "3")
    fake = _fake_jax()
    _jax._persistent_cache(fake)
    assert not hasattr(fake.config, "jax_persistent_cache_min_compile_time_secs")


def test_compiled_programs_are_reused_by_a_fresh_process(tmp_path):
    import os

    folder = tmp_path / "jax"
    # every program is stored, however quick its compilation (the default keeps those
    # over a second, which depends on the machine)
    env = {
        **os.environ,
        _jax.CACHE_ENV: str(folder),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    }
    code = """
import jax
import numpy as np
import aeroid
from aeroid.models import compiled as _compiled
_compiled.COMPILE_AFTER_CALLS = 0  # compile at once
def pendulum(t, x, u, p):  # written with numpy, as users do
    return np.array([x[1], -p["k"] * np.sin(x[0]) - p["c"] * x[1] + u[0]])
model = aeroid.Model(["theta", "omega"], ["torque"], {"k": 4.0, "c": 0.3}, pendulum)
t = np.arange(101) * 0.02
model.simulate_batch(t, np.sin(t)[:, None], np.array([[0.1, 0.0]]), {"k": np.array([4.0])},
                     method="rk4")
assert _compiled._CACHE[model][("fn", "dynamics")] is not None
print(jax.config.jax_compilation_cache_dir)
"""

    def programs() -> dict[str, int]:
        return {p.name: p.stat().st_mtime_ns for p in folder.glob("*-cache")}

    first = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert first.stdout.strip().splitlines()[-1] == str(folder)
    stored = programs()
    assert stored
    subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert programs() == stored  # read back: not compiled and written again


def test_a_program_another_process_compiles_is_waited_for_and_read(tmp_path):
    import fcntl
    import os
    import threading

    compiled: list[str] = []
    on_disk: dict[str, str] = {}

    def compile_and_write(backend, computation, devices, options, callbacks, name, key):
        compiled.append(key)
        return f"compiled {key}"

    def read(name, key, options, backend, devices):
        return on_disk.get(key), 1

    once = _jax._compile_once(compile_and_write, read, tmp_path)
    # nobody else compiles it: compiled here, the cache not read again
    assert once(None, None, None, None, (), "jit_f", "k1") == "compiled k1"
    assert compiled == ["k1"]
    assert not list(tmp_path.iterdir())  # its lock file removed
    # another process holds the program's lock: wait, then take what it wrote
    for written, expected in (("from disk", "from disk"), (None, "compiled k2")):
        compiled.clear()
        fd = os.open(tmp_path / _jax._lock_name("k2"), os.O_RDWR | os.O_CREAT, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)
        got: list[str] = []

        def call(into: list[str] = got) -> None:
            into.append(once(0, 0, 0, 0, (), "f", "k2"))

        waiter = threading.Thread(target=call)
        waiter.start()
        waiter.join(0.3)
        assert waiter.is_alive() and not compiled  # waiting, not compiling
        if written is not None:
            on_disk["k2"] = written
        os.close(fd)
        waiter.join(10)
        # the other's program where it wrote one, else (too quick to keep) compiled here
        assert got == [expected]
        assert compiled == ([] if written is not None else ["k2"])
        on_disk.clear()


def test_processes_that_meet_a_program_together_compile_it_once(tmp_path):
    """Two fresh processes on one cache folder reach one program at the same moment (a
    campaign's workers on their first flights): one compiles it, the other reads it."""
    import os

    folder = tmp_path / "jax"
    env = {
        **os.environ,
        _jax.CACHE_ENV: str(folder),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    }
    code = """
import pathlib, sys, time
import jax
import numpy as np
from aeroid.models.jax_compiled import require_jax
from jax._src import compiler
_, jnp = require_jax()
real = compiler.backend_compile_and_load
count = []
def slow(*args, **kwargs):  # a compilation long enough for the other process to meet it
    count.append(1)
    time.sleep(1.0)
    return real(*args, **kwargs)
compiler.backend_compile_and_load = slow
here, other = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
here.touch()
while not other.exists():  # both imported and set up: start together
    time.sleep(0.01)
f = jax.jit(lambda x: jnp.sin(x) * 3.0 + jnp.cumsum(x))
print(float(np.asarray(f(np.arange(7.0)))[-1]), len(count))
"""
    a, b = tmp_path / "a", tmp_path / "b"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(x), str(y)], stdout=subprocess.PIPE, text=True, env=env
        )
        for x, y in ((a, b), (b, a))
    ]
    outs = [p.communicate(timeout=120)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    expected = float(np.sin(6.0) * 3.0 + 21.0)
    assert [float(o[0]) for o in outs] == pytest.approx([expected, expected], rel=1e-15)
    # one compilation between them (without the lock each process compiled its own)
    assert sorted(int(o[1]) for o in outs) == [0, 1]


def test_a_program_traces_the_model_once_however_often_it_calls_it():
    """The RK4 step calls the dynamics four times: traced once, the program the same."""
    import jax

    from aeroid.models import compiled as _compiled

    traced: list[int] = []

    def pendulum(t, x, u, p):
        if isinstance(x, jax.core.Tracer):
            traced.append(1)
        return np.array([x[1], -p["k"] * np.sin(x[0]) - p["c"] * x[1] + u[0]])

    model = aeroid.Model(["theta", "omega"], ["torque"], {"k": 4.0, "c": 0.3}, pendulum)
    t = np.arange(201) * 0.02
    u = np.sin(t)[None, :, None]
    p = {"k": np.array([4.0]), "c": np.array([0.3])}
    traj = _compiled.compiled_rollout(model, t, np.array([[0.1], [0.0]]), u, p, 2)
    assert traj is not None
    # the check against numpy traces it once, the rollout once more at most (four times
    # a substep before)
    assert 1 <= len(traced) <= 2
    ref = model.simulate_batch(t, u[0], np.array([[0.1, 0.0]]), p, method="rk4", substeps=2)
    np.testing.assert_allclose(traj.states, ref.states, rtol=0, atol=1e-13)


def test_initial_states_with_the_jax_gradient_are_refused_naming_the_way_out(sp_clean):
    with pytest.raises(aeroid.IdentificationError, match=r"estimate_x0 \['alpha'\]: .*'auto'"):
        aeroid.identify(_sp_model(), sp_clean, ["M_q"], gradient="jax", estimate_x0=["alpha"])


def test_the_librarys_aircraft_models_take_every_jax_path():
    # found by an independent suite: simulate_rk4, gradient="jax" and backend="jax"
    # refused aeroid.models.aircraft's own models ("write them with jax.numpy")
    import warnings

    from aeroid.models import aircraft

    c = aircraft.AircraftConstants(
        mass=1200.0, Ixx=1400.0, Iyy=1800.0, Izz=2600.0, S=16.2, b=10.9, cbar=1.49, rho=1.1
    )
    truth = {"Cl_p": -0.47, "Cn_r": -0.1, "Cn_beta": 0.07, "Cl_delta_a": -0.17}
    m = aircraft.lateral(c, V0=45.0, parameters={**truth, "Cn_delta_r": -0.05, "CY_beta": -0.5})
    t = np.arange(0.0, 5.0, 0.02)
    u = np.zeros((t.size, 2))
    u[(t > 0.5) & (t < 1.5), 0] = 0.05
    u[(t > 2.0) & (t < 3.0), 1] = 0.05
    for substeps in (1, 3):
        got = simulate_rk4(m, t, u, np.zeros(4), substeps=substeps)
        want = m.simulate(t, u, np.zeros(4), method="rk4", substeps=substeps)
        np.testing.assert_allclose(np.asarray(got.outputs), want.outputs, rtol=0, atol=1e-13)
    rng = np.random.default_rng(0)
    y = m.simulate(t, u, np.zeros(4), method="rk4").outputs
    channels = {
        n: y[:, i] + 1e-4 * rng.standard_normal(t.size) for i, n in enumerate(m.output_names)
    }
    data = aeroid.FlightData(t, {"delta_a": u[:, 0], "delta_r": u[:, 1], **channels})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exact = aeroid.identify(m, data, list(truth), gradient="jax", estimate_x0=False)
        plain = aeroid.identify(m, data, list(truth), estimate_x0=False)
    for k in truth:
        assert exact.parameters[k] == pytest.approx(plain.parameters[k], rel=1e-9)
        assert exact.stderr[k] == pytest.approx(plain.stderr[k], rel=1e-6)
    lon = aircraft.longitudinal(
        c,
        V0=45.0,
        parameters={"CL_0": 0.4, "CL_alpha": 5.0, "CD_0": 0.03, "Cm_0": 0.02, "Cm_alpha": -0.8}
        | {"Cm_q": -12.0, "Cm_delta_e": -1.0},
    )
    tr = aircraft.trim(lon)
    ul = np.tile(tr.u0, (t.size, 1))
    ul[(t > 0.5) & (t < 1.5), 0] += 0.02
    got = simulate_rk4(lon, t, ul, tr.x0, substeps=2)
    want = lon.simulate(t, ul, tr.x0, method="rk4", substeps=2)
    np.testing.assert_allclose(np.asarray(got.outputs), want.outputs, rtol=1e-12, atol=1e-10)
