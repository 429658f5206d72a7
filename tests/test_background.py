"""Background jobs (aeroid._threads.after_call) and a model's compilation in them: a
model fitted twice compiles in the background, a later fit switches to the compiled
program once it is ready, the results do not depend on which path ran, and a process
exits cleanly (a one-off fit never starts a compiler)."""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap
import threading
import time
from typing import Any

import pytest

from aeroid import _threads
from aeroid._threads import after_call, small_blas, wait_background


def test_a_job_waits_for_the_outermost_call_and_runs_in_another_thread() -> None:
    ran: list[str] = []
    with small_blas:
        with small_blas:
            after_call(lambda: ran.append(threading.current_thread().name))
        assert wait_background(5.0)
        assert ran == []  # deferred: the public call is still open
    assert wait_background(5.0)
    assert ran == ["aeroid-background"]
    after_call(lambda: ran.append("outside"))  # no call open: queued at once
    assert wait_background(5.0)
    assert ran[-1] == "outside"


def test_a_failing_job_is_logged_at_debug_level_and_the_next_still_runs(
    caplog: pytest.LogCaptureFixture,
) -> None:
    ran: list[int] = []

    def fails() -> None:
        raise RuntimeError("no compiler today")

    with caplog.at_level(logging.DEBUG, logger="aeroid"):
        after_call(fails)
        after_call(lambda: ran.append(1))
        assert wait_background(5.0)
    assert ran == [1]
    assert any(r.levelno == logging.DEBUG and r.exc_info for r in caplog.records)


def test_a_background_job_leaves_the_callers_warnings_alone() -> None:
    # the warnings filters are one state for the process: a job that saved and
    # restored them (catch_warnings) around its work would undo, on leaving, the
    # recording the caller's thread set up meanwhile, and its warning would be lost
    import warnings

    from aeroid._threads import quiet_warnings

    inside, leave = threading.Event(), threading.Event()

    def job() -> None:
        with quiet_warnings():
            inside.set()
            leave.wait(5.0)

    after_call(job)
    assert inside.wait(5.0)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        leave.set()
        assert wait_background(5.0)
        warnings.warn("the caller's own", UserWarning, stacklevel=1)
    assert [str(w.message) for w in seen] == ["the caller's own"]
    # in the caller's thread the block is quiet
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with quiet_warnings():
            warnings.warn("hushed", UserWarning, stacklevel=1)
    assert seen == []


def test_threads_record_their_own_warnings_and_leave_the_process_as_it_was() -> None:
    # two tasks in threads, the first to enter the last to leave: with catch_warnings
    # the second's exit would restore the first's recording for good, and every later
    # warning of the process would go to a list nobody reads
    import warnings

    from aeroid._threads import quiet_warnings, record_warnings

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    got: dict[str, list[str]] = {}

    def task(name: str, enter: threading.Event, wait: threading.Event) -> None:
        with record_warnings() as seen:
            enter.set()
            assert wait.wait(5.0)
            warnings.warn(f"from {name}", UserWarning, stacklevel=1)
            with quiet_warnings():
                warnings.warn("hushed", UserWarning, stacklevel=1)
        if name == "a":
            a_out.set()
        got[name] = [str(w.message) for w in seen]

    before = (warnings.showwarning, list(warnings.filters))
    a = threading.Thread(target=task, args=("a", a_in, b_in))
    b = threading.Thread(target=lambda: a_in.wait(5.0) and task("b", b_in, a_out))
    a.start()
    b.start()
    a.join(10.0)
    b.join(10.0)
    assert got == {"a": ["from a"], "b": ["from b"]}
    assert (warnings.showwarning, list(warnings.filters)) == before
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        warnings.warn("the caller's own", UserWarning, stacklevel=1)
    assert [str(w.message) for w in seen] == ["the caller's own"]


def test_wait_background_times_out_while_a_job_runs() -> None:
    release = threading.Event()
    after_call(release.wait)
    try:
        assert not wait_background(0.05)
    finally:
        release.set()
    assert wait_background(5.0)


def _exit_of(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def test_at_exit_the_running_job_ends_and_the_queued_ones_are_dropped() -> None:
    out = _exit_of(
        """
        import time
        from aeroid._threads import after_call
        after_call(lambda: (time.sleep(1.0), print("running job ran")))
        after_call(lambda: print("queued job ran"))
        time.sleep(0.2)
        print("done")
        """
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:2] == ["done", "running job ran"]
    assert "queued" not in out.stdout


def test_a_process_that_exits_while_a_model_compiles_exits_cleanly() -> None:
    pytest.importorskip("jax")
    out = _exit_of(
        f"""
        import sys
        sys.path.insert(0, {str(__import__("pathlib").Path(__file__).parent)!r})
        import aeroid
        from aeroid import _threads
        from test_fast_shooting import FIT, TRUTH, _flight, _model
        model = _model("exit_while_compiling")
        data = _flight(model, seed=3)
        guess = {{k: 1.2 * TRUTH[k] for k in FIT}}
        opts = {{"simulate_options": {{"method": "rk4", "substeps": 2}}}}
        aeroid.identify(model, data, guess, **opts)
        print("one fit, no compiler:", _threads._worker is None)
        aeroid.identify(model, data, guess, **opts)  # queues the compilation
        print("exiting")
        """
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "one fit, no compiler: True" in out.stdout
    assert "FATAL" not in out.stderr and "terminate" not in out.stderr


# -- a model's sensitivities compiled in the background ----------------------------------


def _case(name: str) -> tuple[Any, Any, dict[str, float], dict[str, Any]]:
    pytest.importorskip("jax")
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from test_fast_shooting import FIT, TRUTH, _flight, _model

    model = _model(name)
    data = _flight(model, seed=3)
    guess = {k: 1.2 * TRUTH[k] for k in FIT}
    return model, data, guess, {"simulate_options": {"method": "rk4", "substeps": 2}}


def test_the_fit_after_the_first_runs_in_numpy_until_the_program_is_ready() -> None:
    import aeroid
    from aeroid.models import compiled as _compiled

    model, data, guess, opts = _case("background_switch")
    first = aeroid.identify(model, data, guess, **opts)
    entry = _compiled._CACHE[model]
    assert ("background", "sensitivities") not in entry  # one fit: nothing queued
    release = threading.Event()
    after_call(release.wait)  # holds the background thread: the compilation queues
    try:
        second = aeroid.identify(model, data, guess, **opts)  # numpy, and queues it
        assert entry[("background", "sensitivities")] == "queued"
        again = aeroid.identify(model, data, guess, **opts)  # not ready: numpy again
        assert not entry.get("sensitivities_compiled")
        assert ("fn", "dynamics") not in entry  # nothing compiled in the foreground
    finally:
        release.set()
    assert wait_background(120.0)
    assert entry[("background", "sensitivities")] == "ready"
    third = aeroid.identify(model, data, guess, **opts)
    assert entry.get("sensitivities_compiled")
    for k in first.parameters:
        assert abs(again.parameters[k] - second.parameters[k]) < 1e-8 * first.stderr[k], k
        # numpy again (Newton from the last trajectory: the same solution, to rounding)
        assert abs(second.parameters[k] - first.parameters[k]) < 1e-8 * first.stderr[k], k
        # exact vs Newton-over-the-record sensitivities: the same estimate
        assert abs(third.parameters[k] - first.parameters[k]) < 1e-4 * first.stderr[k], k
        assert third.stderr[k] == pytest.approx(first.stderr[k], rel=1e-5), k


def test_a_failed_background_compilation_keeps_numpy_silently(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    import warnings

    import aeroid
    from aeroid.models import compiled as _compiled

    model, data, guess, opts = _case("background_fails")

    def broken(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("XLA is out of order")

    monkeypatch.setattr(_compiled, "_compiled", broken)
    with caplog.at_level(logging.DEBUG, logger="aeroid"):
        first = aeroid.identify(model, data, guess, **opts)
        aeroid.identify(model, data, guess, **opts)  # queues the compilation
        assert wait_background(120.0)
    entry = _compiled._CACHE[model]
    assert entry[("background", "sensitivities")] == "failed"
    assert any("compiling sensitivities" in r.getMessage() for r in caplog.records)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # silently: no warning either
        second = aeroid.identify(model, data, guess, **opts)
    assert not entry.get("sensitivities_compiled")
    for k in first.parameters:
        assert abs(second.parameters[k] - first.parameters[k]) < 1e-8 * first.stderr[k], k


def test_background_off_compiles_the_second_fit_in_the_foreground(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import aeroid
    from aeroid.models import compiled as _compiled

    monkeypatch.setattr(_compiled, "BACKGROUND", False)
    model, data, guess, opts = _case("background_off")
    aeroid.identify(model, data, guess, **opts)
    aeroid.identify(model, data, guess, **opts)
    assert ("background", "sensitivities") not in _compiled._CACHE[model]
    assert _compiled._CACHE[model].get("sensitivities_compiled")


def test_the_library_thread_is_a_daemon() -> None:
    after_call(lambda: None)
    assert wait_background(5.0)
    worker = _threads._worker
    assert worker is not None and worker.daemon


def test_the_input_noise_program_compiles_in_the_background_too() -> None:
    import numpy as np

    pytest.importorskip("jax")
    from test_fast_shooting import FIT, TRUTH, X0, _controls, _model

    from aeroid.models import compiled as _compiled

    model = _model("background_input_noise")
    t = np.arange(201) * 0.05
    u = _controls(t)
    inv = np.array([1.0 / 0.002**2, 1.0 / 0.004**2, 0.0, 1.0 / 0.003**2, 1.0 / 0.02**2])
    sigma = np.array([0.001, 0.002, 0.0])
    entry = _compiled._entry(model)
    entry["sensitivities_compiled"] = True  # a fit that ran compiled
    first = _compiled.input_noise_scatter(model, t, u, X0, TRUTH, FIT, [0], 2, inv, sigma)
    assert first is not None
    assert entry[("background", "input_noise")] == "queued"  # numpy now, compiled later
    assert wait_background(120.0)
    assert entry[("background", "input_noise")] == "ready"
    again = _compiled.input_noise_scatter(model, t, u, X0, TRUTH, FIT, [0], 2, inv, sigma)
    assert again is not None
    d = np.sqrt(np.diag(again[2]))
    np.testing.assert_allclose(first[0], again[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(first[2] / np.outer(d, d), again[2] / np.outer(d, d), atol=1e-6)


@pytest.mark.slow
def test_no_background_job_is_the_first_to_import_jax() -> None:
    """The second fit of a model queues its compilation, whose job imports JAX alone
    (`_threads.alone`: no public call runs meanwhile). Imported beside the caller's
    next call, a half-made `jax` sat in sys.modules and that call's SciPy array checks
    (`smooth(method="local")`, `savgol_filter`) failed on ``jax.Array`` every time."""
    pytest.importorskip("jax")
    out = _exit_of(
        f"""
        import sys, warnings
        warnings.simplefilter("ignore")
        sys.path.insert(0, {str(__import__("pathlib").Path(__file__).parent)!r})
        import aeroid
        from _compat_flight import simulated_flight
        d = simulated_flight(8.0, 50.0, errors={{}}, seed=2)
        aeroid.check_compatibility(d)
        aeroid.check_compatibility(d)
        aeroid.smooth(d, ["alpha"], method="local", window=11)
        print("OK")
        """
    )
    assert out.returncode == 0 and "OK" in out.stdout, out.stderr[-800:]


def test_alone_waits_for_the_callers_and_holds_new_ones_off() -> None:
    order: list[str] = []
    inside = threading.Event()

    def job() -> None:
        with _threads.alone():
            order.append("alone")
            inside.set()
            time.sleep(0.2)
            order.append("alone done")

    with small_blas:
        worker = threading.Thread(target=job)
        worker.start()
        time.sleep(0.2)
        assert order == []  # a caller's public call is open: the job waits
    assert inside.wait(5.0)
    with small_blas:  # held off until the job's block ends
        order.append("next call")
    worker.join()
    assert order == ["alone", "alone done", "next call"]
