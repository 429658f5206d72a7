"""BLAS threads: the library runs its small-matrix loops on one thread and gives the
caller's settings back (aeroid._threads)."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (SciPy's own BLAS loaded, so both libraries are checked)
from threadpoolctl import ThreadpoolController, threadpool_limits

import aeroid
from aeroid._threads import blas_threads, small_blas
from aeroid.models import catalog

_BLAS = ThreadpoolController().select(user_api="blas").lib_controllers  # after numpy and SciPy


def _blas() -> list[int]:
    return [int(lib.num_threads) for lib in _BLAS]


pytestmark = pytest.mark.skipif(not _blas(), reason="no BLAS library that threadpoolctl controls")


def test_decorated_call_runs_on_one_blas_thread_and_restores_the_callers_limits():
    seen: list[list[int]] = []

    @small_blas
    def work() -> float:
        seen.append(_blas())
        return float(np.linalg.det(np.eye(3)))

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas()
        assert work() == 1.0
        assert seen == [[1] * len(before)]
        assert _blas() == before  # the caller's two threads are back
    with threadpool_limits(limits=1, user_api="blas"):  # already one thread: left alone
        assert work() == 1.0 and _blas() == [1] * len(before)


def test_nested_calls_do_not_relimit_and_an_exception_still_restores():
    depth: list[list[int]] = []

    @small_blas
    def inner() -> None:
        depth.append(_blas())

    @small_blas
    def outer() -> None:
        inner()
        depth.append(_blas())  # still one thread after the nested call returned
        raise ValueError("boom")

    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas()
        with pytest.raises(ValueError, match="boom"):
            outer()
        assert depth == [[1] * len(before)] * 2
        assert _blas() == before
        with small_blas:  # the context-manager form
            assert set(_blas()) == {1}
            inner()
            assert set(_blas()) == {1}
        assert _blas() == before


def test_a_limit_held_by_another_thread_ends_with_the_last_call():
    # BLAS limits are per process: a call ending in one thread while another
    # thread's call still runs must not give the limits back under it. (Which
    # thread's setting OpenBLAS then reports is its business, so the count of
    # open calls is checked here, not the thread count.)
    from aeroid import _threads

    started, release = threading.Event(), threading.Event()

    @small_blas
    def hold() -> None:
        started.set()
        release.wait(10)

    worker = threading.Thread(target=hold)
    worker.start()
    assert started.wait(10)
    assert _threads._active == 1
    with small_blas:
        assert _threads._active == 2
    assert _threads._active == 1  # the worker's call still holds the limit
    release.set()
    worker.join(10)
    assert _threads._active == 0 and not _threads._saved


def test_public_calls_run_their_callbacks_on_one_blas_thread():
    seen: list[int] = []

    def dynamics(t, x, u, p):
        seen.extend(_blas())
        return np.array([-p["k"] * x[0] + u[0]])

    model = aeroid.Model(
        states=["y"], controls=["u"], parameters={"k": 1.0}, dynamics=dynamics, name="lag"
    )
    t = np.linspace(0.0, 2.0, 41)
    data = aeroid.FlightData(t, {"u": np.ones_like(t), "y": 1.0 - np.exp(-t)})
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas()
        seen.clear()  # Model() probes its dynamics once, outside any numerical call
        model.simulate(t, data, [0.0])
        assert seen and set(seen) == {1}
        seen.clear()
        aeroid.validate(model, data, {"k": 1.0})
        assert seen and set(seen) == {1}
        assert _blas() == before
    assert blas_threads()  # every BLAS the library saw


def test_public_entry_points_are_wrapped():
    from aeroid.models.model import Model

    for fn in (
        aeroid.identify,
        aeroid.validate,
        aeroid.filter_states,
        aeroid.sensitivities,
        aeroid.frequency_response,
        aeroid.infer,
        aeroid.propagate,
        aeroid.design_experiment,
        Model.simulate,
        Model.simulate_batch,
    ):
        assert hasattr(fn, "__wrapped__"), fn.__qualname__
    assert catalog.short_period().simulate.__doc__  # the docstring survives the wrapper


def _where(fn):
    """The files the warnings of `fn()` are attributed to."""
    import warnings

    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        fn()
    return {(w.category.__name__, w.filename) for w in rec}


def test_warnings_of_public_calls_point_at_the_caller_not_the_wrapper():
    # the wrapper adds a frame: each warning's stacklevel counts it
    model = aeroid.Model(
        states=["y"],
        controls=["u"],
        parameters={"K": 2.0, "g": 1.5, "tau": 0.5},
        dynamics=lambda t, x, u, p: np.array([(p["K"] * p["g"] * u[0] - x[0]) / p["tau"]]),
    )
    t = np.linspace(0.0, 4.0, 81)
    u = (t > 1.0).astype(float)
    clean = aeroid.FlightData(t, {"u": u, "y": model.simulate(t, u, [0.0]).state("y")})
    rng = np.random.default_rng(0)
    noisy = aeroid.FlightData(t, {"u": u, "y": clean["y"] + 0.01 * rng.standard_normal(t.size)})
    here = {__file__}
    cases = {
        "identify (unidentifiable)": lambda: aeroid.identify(model, noisy, ["K", "g"]),
        "identify (not converged)": lambda: aeroid.identify(
            model, noisy, ["K", "tau"], max_iterations=1
        ),
        "identify filter error": lambda: aeroid.identify(
            model,
            noisy,
            ["K", "g"],
            method="filter_error",
            process_noise={"y": 1e-6},
            measurement_noise={"y": 1e-4},
        ),
        "sensitivities": lambda: aeroid.sensitivities(model, clean, ["K", "g", "tau"]),
        "frequency_response": lambda: aeroid.frequency_response(model, noisy),
        "validate": lambda: aeroid.validate(model, noisy, None, whiteness_lags=500),
        "infer": lambda: aeroid.infer(
            model,
            noisy,
            {"K": aeroid.Normal(3.0, 1.0), "tau": aeroid.Normal(0.5, 0.2)},
            n_walkers=8,
            n_steps=20,
            seed=0,
        ),
    }
    wrong = {}
    for name, call in cases.items():
        files = {f for _, f in _where(call)}
        if not files or not files <= here:
            wrong[name] = files
    assert not wrong
