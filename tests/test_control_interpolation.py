"""Controls between samples: straight lines (the default) or the local cubic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeroid import FlightData, Model, identify
from aeroid.errors import FilterError, IdentificationError, SimulationError
from aeroid.estimation._output_error import shifted_controls
from aeroid.estimation.filtering import filter_states
from aeroid.models.integration import control_slopes, controls_at


def _integrator(t, x, u, p):
    return u[:1] * p["g"]


def _lag(t, x, u, p):
    return np.stack([-p["a"] * x[0] + p["b"] * u[0]])


INTEGRATOR = Model(["x"], ["u"], {"g": 1.0}, _integrator, name="integrator")
LAG = Model(["x"], ["u"], {"a": 2.0, "b": 1.0}, _lag, name="lag")


def _sine_error(n: int, interpolation: str, method: str) -> float:
    """Largest error of x' = sin(3 t) integrated over [0, 4] from n samples."""
    t = np.linspace(0.0, 4.0, n)
    sim = INTEGRATOR.simulate(
        t,
        np.sin(3.0 * t)[:, None],
        [0.0],
        method=method,
        substeps=1 if method == "rk4" else None,
        rtol=1e-12,
        atol=1e-14,
        control_interpolation=interpolation,
    )
    return float(np.max(np.abs(sim.state("x") - (1.0 - np.cos(3.0 * t)) / 3.0)))


@pytest.mark.parametrize("method", ["rk4", "RK45", "LSODA"])
def test_convergence_order_of_the_integral_of_a_sine(method):
    # x' = u: the states are the integral of the interpolated controls; straight lines
    # err by O(h^2), the cubic by O(h^4) (rate measured over h and h/2)
    lin = [_sine_error(n, "linear", method) for n in (41, 81)]
    cub = [_sine_error(n, "cubic", method) for n in (41, 81)]
    assert 1.9 < math.log2(lin[0] / lin[1]) < 2.1
    assert 3.8 < math.log2(cub[0] / cub[1]) < 4.2
    assert cub[0] < lin[0] / 40


def test_a_cubic_input_is_integrated_exactly_inside_the_record():
    # on a uniform grid each inner interval's integral is h(-u0 + 13u1 + 13u2 - u3)/24,
    # exact for cubics: only the two end intervals (the parabola through three samples)
    # err, by h^4 times the cubic's third derivative: x(t) - x_exact is constant after
    # the first interval
    h = 0.1
    t = np.arange(41) * h
    u = t**3 - 2.0 * t**2 + t
    sim = INTEGRATOR.simulate(
        t, u[:, None], [0.0], method="rk4", substeps=1, control_interpolation="cubic"
    )
    err = sim.state("x") - (t**4 / 4.0 - 2.0 * t**3 / 3.0 + t**2 / 2.0)
    first = err[1]
    # the first interval's rule h(5u0 + 8u1 - u2)/12 misses a cubic's integral by
    # u''' h^4 / 24 (u''' = 6)
    assert first == pytest.approx(-6.0 * h**4 / 24.0, rel=1e-9)
    np.testing.assert_allclose(err[1:-1], first, atol=1e-13)


def test_straight_lines_stay_the_default_bit_for_bit():
    t = np.linspace(0.0, 4.0, 81)
    u = np.sin(3.0 * t)[:, None]
    for method in ("rk4", "RK45", "auto"):
        plain = LAG.simulate(t, u, [0.1], method=method)
        named = LAG.simulate(t, u, [0.1], method=method, control_interpolation="linear")
        assert np.array_equal(plain.states, named.states)
    cubic = LAG.simulate(t, u, [0.1], method="rk4", control_interpolation="cubic")
    assert not np.array_equal(cubic.states, LAG.simulate(t, u, [0.1], method="rk4").states)


def test_the_cubic_reproduces_quadratics_and_rings_after_a_step():
    t = np.cumsum(np.r_[0.0, np.linspace(0.05, 0.15, 20)])  # a non-uniform grid
    q = 1.0 - 2.0 * t + 0.7 * t**2
    fine = np.linspace(t[0], t[-1], 997)
    np.testing.assert_allclose(
        controls_at(t, q[:, None], fine, "cubic")[:, 0],
        1.0 - 2.0 * fine + 0.7 * fine**2,
        atol=1e-12,
    )
    np.testing.assert_allclose(control_slopes(t, q[:, None])[:, 0], -2.0 + 1.4 * t, atol=1e-12)
    # a unit step: the interval before the jump dips to -2/27 at two thirds of the way, the
    # one after it overshoots by as much (why straight lines stay the default)
    s = np.arange(10.0)
    step = (s >= 5).astype(float)[:, None]
    assert controls_at(s, step, np.array([3.0 + 2.0 / 3.0]), "cubic")[0, 0] == pytest.approx(
        -2 / 27
    )
    assert controls_at(s, step, np.array([5.0 + 1.0 / 3.0]), "cubic")[0, 0] == pytest.approx(
        29 / 27
    )
    assert np.all(controls_at(s, step, np.linspace(0, 9, 500), "linear") >= 0.0)


def test_delayed_controls_follow_the_cubic():
    t = np.arange(30) * 0.1
    u = np.stack([t**2, np.cos(t)], axis=1)
    got = shifted_controls(t, u, [0], [0.037], "cubic")
    inner = slice(2, -2)  # the quadratic is reproduced wherever t - tau lies inside
    np.testing.assert_allclose(got[inner, 0], (t[inner] - 0.037) ** 2, atol=1e-12)
    assert np.array_equal(got[:, 1], u[:, 1])
    # straight lines bend a parabola by h^2/8 at most: the linear shift misses it
    lin = shifted_controls(t, u, [0], [0.037])
    assert np.max(np.abs(lin[inner, 0] - (t[inner] - 0.037) ** 2)) > 1e-3


def _sine_record(seed: int, sigma: float) -> tuple[FlightData, float]:
    """The lag x' = -2x + u driven by sin(w t), sampled every T = 0.1 s at wT = 0.6, the
    exact continuous response with white noise of `sigma`; returns it and wT."""
    T, w, a = 0.1, 6.0, 2.0
    t = np.arange(0.0, 20.0 + 1e-9, T)
    amp, ph = 1.0 / math.hypot(a, w), math.atan2(w, a)
    x = amp * np.sin(w * t - ph) + amp * math.sin(ph) * np.exp(-a * t)
    rng = np.random.default_rng(seed)
    return FlightData(t, {"u": np.sin(w * t), "x": x + sigma * rng.standard_normal(t.size)}), w * T


def _loss(interpolation: str, nu: float) -> float:
    """The share of a sine of nu radians per sample that the interpolant keeps at its
    own frequency: sinc^2(nu/2) for straight lines, and for the cubic
    (18 - 24 cos nu + 6 cos 2nu + nu (2 sin 2nu - 4 sin nu)) / nu^4 = 1 - nu^4/80 + ..."""
    if interpolation == "linear":
        return (math.sin(nu / 2) / (nu / 2)) ** 2
    c, s = math.cos(nu), math.sin(nu)
    return (18 - 24 * c + 6 * (2 * c * c - 1) + nu * (4 * s * c - 4 * s)) / nu**4


def test_loss_formulas_against_a_long_record():
    # the interpolant's component at the sine's own frequency over whole periods
    nu = 0.6
    k = np.arange(round(2 * math.pi / nu * 50) + 3)
    T = 1.0
    t = k * T
    u = np.sin(nu * t)[:, None]
    fine = np.linspace(t[1], t[1] + 50 * 2 * math.pi / nu, 200_001)[:-1]
    for interp in ("linear", "cubic"):
        v = controls_at(t, u, fine, interp)[:, 0]
        gain = 2.0 * np.mean(v * np.sin(nu * fine))
        assert gain == pytest.approx(_loss(interp, nu), abs=2e-4)
    assert 1.0 - _loss("cubic", nu) == pytest.approx(nu**4 / 80, rel=0.05)


@pytest.mark.parametrize("method", ["output_error", "filter_error"])
def test_a_control_derivative_from_a_coarse_sine(method):
    # b of x' = -a x + b u with the sine sampled at 0.6 rad per sample: straight lines
    # read b larger by 1/sinc^2(0.3) - 1 = 3.05 %, the cubic by 1/G - 1 = 0.16 %; the
    # images of the sine above the sample rate add about 0.05 % to either
    sigma = 2e-3
    got: dict[str, list[tuple[float, float]]] = {"linear": [], "cubic": []}
    for seed in range(3):
        data, nu = _sine_record(seed, sigma)
        for interp in got:
            if method == "output_error":
                r = identify(
                    LAG,
                    data,
                    ["b"],
                    simulate_options={"control_interpolation": interp, "method": "rk4"},
                )
            else:
                r = identify(
                    LAG,
                    data,
                    ["b"],
                    method="filter_error",
                    process_noise={"x": 1e-8},
                    measurement_noise={"x": sigma**2},
                    filter_options={"control_interpolation": interp},
                )
            got[interp].append((r.parameters["b"], r.standard_errors["b"]))
    for interp, fits in got.items():
        expected = 1.0 / _loss(interp, nu)
        for b, se in fits:
            # four standard errors of the noise and the images' 0.1 %
            assert abs(b - expected) < 4 * se + 1e-3, (interp, b, expected, se)
    lin = np.mean([b for b, _ in got["linear"]])
    cub = np.mean([b for b, _ in got["cubic"]])
    assert lin - 1.0 > 0.025 and abs(cub - 1.0) < 0.004


def test_paths_that_hold_straight_lines_refuse_the_cubic():
    t = np.linspace(0.0, 2.0, 21)
    u = np.sin(t)[:, None]
    with pytest.raises(SimulationError, match="exact"):
        LAG.simulate(t, u, [0.0], method="exact", control_interpolation="cubic")
    with pytest.raises(SimulationError, match="euler"):
        LAG.simulate(t, u, [0.0], method="euler", control_interpolation="cubic")
    with pytest.raises(SimulationError, match=r"control_interpolation.*'spline'"):
        LAG.simulate(t, u, [0.0], control_interpolation="spline")
    data = FlightData(t, {"u": u[:, 0], "x": np.zeros(t.size)})
    with pytest.raises(FilterError, match=r"control_interpolation.*'quintic'"):
        filter_states(
            LAG,
            data,
            process_noise={"x": 1e-4},
            measurement_noise={"x": 1e-4},
            control_interpolation="quintic",
        )
    with pytest.raises(IdentificationError, match=r"control_interpolation.*'akima'"):
        identify(
            LAG,
            data,
            ["b"],
            gradient="jax",
            simulate_options={"control_interpolation": "akima"},
        )
    with pytest.raises(IdentificationError, match="control_interpolation"):
        identify(LAG, data, ["b"], simulate_options={"control_interpolation": "akima"})


def test_filter_states_propagates_the_cubic():
    # a linear model with cubic controls: propagated by RK4, not the exact (straight-line)
    # discretisation; with almost no process noise the filter follows the simulation
    t = np.arange(0.0, 5.0 + 1e-9, 0.1)
    u = np.sin(6.0 * t)
    sim = LAG.simulate(t, u[:, None], [0.0], method="rk4", control_interpolation="cubic")
    data = FlightData(t, {"u": u, "x": sim.state("x")})
    for interp in ("linear", "cubic"):
        res = filter_states(
            LAG,
            data,
            process_noise={"x": 1e-14},
            measurement_noise={"x": 1.0},
            x0=[0.0],
            P0={"x": 1e-14},
            smooth=False,
            control_interpolation=interp,
        )
        miss = np.max(np.abs(res.filtered_states[:, 0] - sim.state("x")))
        if interp == "cubic":
            assert miss < 1e-6
        else:
            assert miss > 1e-3


def _two_integrators(t, x, u, p):
    return u[:2] * p["g"]


def test_a_mapping_names_the_cubic_controls():
    # each control its own integrator: the named control's state follows the cubic,
    # the other's straight lines, each as when all controls are interpolated alike
    model = Model(["x1", "x2"], ["u1", "u2"], {"g": 1.0}, _two_integrators, name="two")
    t = np.linspace(0.0, 4.0, 41)
    u = np.stack([np.sin(3.0 * t), np.cos(2.0 * t)], axis=1)

    def run(how):
        return model.simulate(
            t, u, [0.0, 0.0], method="rk4", substeps=2, control_interpolation=how
        ).states

    mixed, cubic, straight = run({"u1": "cubic"}), run("cubic"), run("linear")
    np.testing.assert_allclose(mixed[:, 0], cubic[:, 0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(mixed[:, 1], straight[:, 1], rtol=0, atol=1e-14)
    assert np.max(np.abs(cubic[:, 1] - straight[:, 1])) > 1e-4
    assert np.array_equal(run({"u1": "linear"}), straight)
    with pytest.raises(SimulationError, match=r"\['u3'\] are not controls"):
        run({"u3": "cubic"})
    with pytest.raises(SimulationError, match=r"control_interpolation\['u2'\]: 'spline'"):
        run({"u2": "spline"})
    # delayed controls take each column's own interpolation
    moved = shifted_controls(t, u, [0, 1], [0.03, 0.03], ("cubic", "linear"))
    np.testing.assert_allclose(moved[:, 1], np.interp(t - 0.03, t, u[:, 1]), atol=1e-15)
    np.testing.assert_allclose(
        moved[:, 0], controls_at(t, u[:, :1], t - 0.03, "cubic")[:, 0], atol=1e-15
    )
