"""Optimal experiment design."""

from __future__ import annotations

import re

import numpy as np
import pytest

import aeroid
from aeroid import ChannelError, FlightData, IdentificationError, Model
from aeroid.models import catalog
from aeroid.uncertainty.design import ExperimentDesign, design_experiment
from aeroid.uncertainty.maneuvers import Chirp, Doublet, Multisine, Multistep

TRUTH = dict(catalog.SHORT_PERIOD_TRUTH)
NOISE = {"alpha": 0.005, "q": 0.01}
FAST = {"maxiter": 4, "popsize": 3}


def spec_multisine() -> Multisine:
    return Multisine("elevator", frequencies=(0.2, 0.5, 1.0, 1.5), amplitude=(0.0, 0.05))


@pytest.fixture(scope="module")
def spec_design() -> ExperimentDesign:
    """The spec's example design (8 s at 25 Hz, maxiter 4, popsize 3)."""
    return design_experiment(
        catalog.short_period(),
        spec_multisine(),
        ["M_q", "M_delta"],
        values=TRUTH,
        noise=NOISE,
        duration=8.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options=FAST,
    )


def test_spec_example_record(spec_design):
    d = spec_design
    assert isinstance(d, ExperimentDesign)
    assert d.time.shape == (201,) and d.controls.shape == (201, 1)
    assert set(d.design) == set(spec_multisine().variable_names)
    assert d.criterion_value <= d.initial_criterion_value
    for n in ("M_q", "M_delta"):
        assert d.predicted_stderr[n] <= d.initial_stderr[n] * (1 + 1e-9)
    assert re.fullmatch(
        r"designed multisine on 'elevator': dominant energy [\d.]+(-[\d.]+)? Hz, peak amplitude "
        r"0\.05; predicted stderr improves [\d.]+x over the initial design for M_(q|delta)",
        d.recommendation,
    ), d.recommendation
    flight = d.to_flight_data()
    np.testing.assert_array_equal(flight["elevator"], d.control("elevator"))
    text = d.summary()
    assert "Recommendation" in text and "M_delta" in text and "D-optimal" in text
    with pytest.raises(ValueError):
        d.controls[0, 0] = 1.0


def test_amplitude_pinned_to_bound_for_linear_dynamics(spec_design):
    # Information grows with amplitude² for linear dynamics: the optimum uses the limit.
    assert np.max(np.abs(spec_design.controls)) == pytest.approx(0.05, rel=1e-2)
    d = design_experiment(
        catalog.short_period(),
        Doublet("elevator", amplitude=(0.01, 0.05), width=(0.5, 2.0), start=1.0),
        ["Z_alpha", "M_alpha", "M_q", "M_delta"],
        values=TRUTH,
        noise=NOISE,
        duration=8.0,
        sample_rate=25.0,
        seed=1,
        optimizer_options=FAST,
    )
    assert d.design["amplitude"] == pytest.approx(0.05, rel=1e-2)


def test_amplitude_pinned_to_bound_for_near_linear_dynamics():
    # a mild cubic pitch stiffness (≈1 % of M_alpha at 0.05 rad): still monotone information
    def dynamics(t, x, u, p):
        alpha, q = x[0], x[1]
        return np.array(
            [
                p["Z_alpha"] * alpha + q,
                p["M_alpha"] * alpha - 20.0 * alpha**3 + p["M_q"] * q + p["M_delta"] * u[0],
            ]
        )

    model = Model(states=["alpha", "q"], controls=["elevator"], parameters=TRUTH, dynamics=dynamics)
    d = design_experiment(
        model,
        Doublet("elevator", amplitude=(0.01, 0.05), width=1.0),
        ["M_q", "M_delta"],
        noise=NOISE,
        duration=6.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options=FAST,
    )
    assert d.design["amplitude"] == pytest.approx(0.05, rel=1e-2)


def _fit(model: Model, data: FlightData, names: list[str]) -> np.ndarray:
    identify = getattr(aeroid, "identify", None)
    if identify is not None:
        res = identify(model, data, names)
        return np.array([res.parameters[n] for n in names])
    import scipy.optimize

    u = data["elevator"]
    y = data.array(["alpha", "q"]) / np.array([NOISE["alpha"], NOISE["q"]])

    def resid(theta):
        p = dict(zip(names, theta, strict=True))
        sim = model.simulate(data.time, u, [0.0, 0.0], p, method="exact")
        return (sim.outputs / np.array([NOISE["alpha"], NOISE["q"]]) - y).ravel()

    return scipy.optimize.least_squares(resid, [model.parameters[n] for n in names]).x


def test_predicted_stderr_matches_fitting_the_flown_design(spec_design):
    # Fly the design 30 times with seeded noise and fit: the spread of the estimates
    # is the achieved stderr. With 30 fits the sample std is known to ~13 %
    # (1/sqrt(2*29)); rel 0.5 leaves room for the residual non-linearity of the fit.
    model = catalog.short_period(TRUTH)
    sim = model.simulate(spec_design.time, spec_design.controls, [0.0, 0.0], method="exact")
    names = ["M_q", "M_delta"]
    est = []
    for seed in range(30):
        data = sim.to_flight_data(noise=NOISE, seed=seed)
        est.append(_fit(model, data, names))
    spread = np.std(np.array(est), axis=0, ddof=1)
    predicted = [spec_design.predicted_stderr[n] for n in names]
    np.testing.assert_allclose(spread, predicted, rtol=0.5)


def test_same_seed_same_design():
    kw = {
        "values": TRUTH,
        "noise": NOISE,
        "duration": 6.0,
        "sample_rate": 25.0,
        "optimizer_options": FAST,
    }
    a = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], seed=7, **kw)
    b = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], seed=7, **kw)
    np.testing.assert_array_equal(a.controls, b.controls)
    assert dict(a.design) == dict(b.design)
    # no seed: one is drawn and recorded, and it repeats the design
    c = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], seed=None, **kw)
    assert isinstance(c.seed, int)
    d = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], seed=c.seed, **kw)
    np.testing.assert_array_equal(c.controls, d.controls)


def test_each_generation_is_one_batched_simulation(monkeypatch):
    sizes = []
    original = Model.simulate_batch

    def counting(self, time, controls, x0, parameters, **kw):
        sizes.append(max(np.size(v) for v in parameters.values()))
        return original(self, time, controls, x0, parameters, **kw)

    monkeypatch.setattr(Model, "simulate_batch", counting)
    d = design_experiment(
        catalog.short_period(),
        spec_multisine(),
        ["M_q", "M_delta"],
        values=TRUTH,
        noise=NOISE,
        duration=4.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options={**FAST, "polish": False},
    )
    # initial design, then the population (3 x 4 = 12 candidates) every generation,
    # then the final comparison: each candidate carries 2 x 2 difference columns, and
    # every batch is padded to the population, so one batch shape is simulated
    assert sizes == [12 * 4] * (d.n_generations + 3)
    # the work counted is the candidates' own, not the padding's
    assert d.n_candidates == 1 + 12 * (d.n_generations + 1) + 2
    assert d.n_simulations == d.n_candidates * 4


def _cubic_pitch_model() -> Model:
    """The short period with a cubic pitch stiffness: integrated by RK4, not exactly."""

    def dynamics(t, x, u, p):
        alpha, q = x[0], x[1]
        return np.array(
            [
                p["Z_alpha"] * alpha + q,
                p["M_alpha"] * alpha - 20.0 * alpha**3 + p["M_q"] * q + p["M_delta"] * u[0],
            ]
        )

    return Model(states=["alpha", "q"], controls=["elevator"], parameters=TRUTH, dynamics=dynamics)


@pytest.mark.parametrize("compiled", [False, True])
def test_padded_batches_give_the_unpadded_criteria_bit_for_bit(monkeypatch, compiled):
    # a batch of three candidates, alone and padded to seven (copies of the last, or of
    # another design): each candidate's information is its own, whatever shares its batch
    from aeroid.models import compiled as _compiled
    from aeroid.uncertainty import design as _design

    if compiled:
        pytest.importorskip("jax")
        monkeypatch.setattr(_compiled, "COMPILE_AFTER_CALLS", 0)
    model = _cubic_pitch_model()
    family = Doublet("elevator", amplitude=(0.01, 0.05), width=(0.5, 2.0))
    names = ["M_alpha", "M_q", "M_delta"]
    t = np.arange(101) / 25.0

    def evaluator(width: int) -> _design._Evaluator:
        return _design._Evaluator(
            model, family, t, None, TRUTH, names, np.array([0.005, 0.01]), [0, 1], "D",
            {}, 1e-6, None, width,
        )  # fmt: skip

    candidates = np.array([[0.02, 0.7], [0.05, 1.9], [0.035, 1.1]])
    plain = evaluator(0)
    f0, ok0 = plain.fisher(candidates)
    c0 = plain.criterion_of(f0, ok0)
    for filler in (None, np.array([0.01, 0.5])):
        padded = evaluator(7)
        f1, ok1 = padded.fisher(candidates, filler=filler)
        np.testing.assert_array_equal(f1, f0)
        np.testing.assert_array_equal(ok1, ok0)
        np.testing.assert_array_equal(padded.criterion_of(f1, ok1), c0)
        assert (padded.n_candidates, padded.n_simulations) == (3, 3 * 2 * len(names))
    assert ok0.all() and np.all(c0 < _design._PENALTY)
    # the designs differ: the check compares three distinct informations
    assert len({float(c) for c in c0}) == 3


def test_a_optimal_and_chirp():
    d = design_experiment(
        catalog.short_period(),
        Chirp("elevator", f0=(0.1, 0.5), f1=(1.0, 3.0), amplitude=(0.0, 0.05)),
        ["Z_alpha", "M_alpha", "M_q", "M_delta"],
        criterion="A",
        values=TRUTH,
        noise=NOISE,
        duration=6.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options=FAST,
    )
    assert d.criterion == "A"
    assert d.criterion_value <= d.initial_criterion_value
    # A criterion = sum of relative Cramér–Rao variances
    rel = sum((d.predicted_stderr[n] / abs(TRUTH[n])) ** 2 for n in d.parameter_names)
    assert d.criterion_value == pytest.approx(rel, rel=1e-6)
    assert d.design["amplitude"] == pytest.approx(0.05, rel=1e-2)


def test_a_seeded_3211_design_stays_in_its_ranges():
    family = Multistep("elevator", amplitude=(0.01, 0.05), width=(0.3, 1.0), start=1.0)
    args = dict(values=TRUTH, noise=NOISE, duration=8.0, sample_rate=25.0, optimizer_options=FAST)
    d = design_experiment(catalog.short_period(), family, ["M_q", "M_delta"], seed=0, **args)
    assert isinstance(d, ExperimentDesign)
    assert set(d.design) == {"amplitude", "width"}
    assert 0.3 <= d.design["width"] <= 1.0
    assert d.criterion_value <= d.initial_criterion_value
    # linear dynamics: information grows with amplitude², so the optimum uses the limit
    assert d.design["amplitude"] == pytest.approx(0.05, rel=1e-2)
    assert np.max(np.abs(d.controls)) <= 0.05 * (1 + 1e-12)
    np.testing.assert_array_equal(
        d.controls, family.signal([d.design[n] for n in family.variable_names], d.time)
    )
    assert d.recommendation.startswith("designed 3-2-1-1 multistep on 'elevator': amplitude ")
    again = design_experiment(catalog.short_period(), family, ["M_q", "M_delta"], seed=0, **args)
    assert again.design == d.design


def test_an_exponential_sweep_design():
    d = design_experiment(
        catalog.short_period(),
        Chirp("elevator", f0=0.1, f1=(1.0, 3.0), amplitude=(0.0, 0.05), sweep="exponential"),
        ["M_q", "M_delta"],
        values=TRUTH,
        noise=NOISE,
        duration=6.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options=FAST,
    )
    assert 1.0 <= d.design["f1"] <= 3.0 and d.criterion_value <= d.initial_criterion_value
    assert "Hz exponential sweep" in d.recommendation


def test_simulator_model_design_loops():
    class Box:
        def __init__(self):
            self._m = catalog.short_period(TRUTH)
            self.name = "box"
            self.controls = ("elevator",)
            self.outputs = ("alpha", "q")
            self.parameters = dict(TRUTH)

        def simulate(self, time, controls=None, x0=None, parameters=None, **options):
            return self._m.simulate(time, controls, x0, parameters, method="exact")

        def simulate_data(self, data, *, x0=None, parameters=None, **options):
            return self.simulate(data.time, data, x0, parameters)

    d = design_experiment(
        Box(),
        Doublet("elevator", amplitude=(0.01, 0.05), width=1.0),
        ["M_delta"],
        noise=NOISE,
        duration=4.0,
        sample_rate=25.0,
        seed=0,
        optimizer_options={"maxiter": 2, "popsize": 3},
    )
    assert d.design["amplitude"] == pytest.approx(0.05, rel=1e-2)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"optimizer_options": {"max_iter": 3}}, IdentificationError, "maxiter"),
        ({"optimizer_options": {"popsize": 0}}, IdentificationError, "popsize"),
        ({"criterion": "E"}, IdentificationError, "criterion"),
        ({"noise": {"nz": 0.1}}, IdentificationError, "nz"),
        ({"duration": -1.0}, IdentificationError, "duration"),
        ({"parameters": ["M_x"]}, IdentificationError, "M_x"),
        ({"maneuver": Doublet("rudder", amplitude=(0.0, 0.1))}, ChannelError, "rudder"),
        (
            {"maneuver": Doublet("elevator", amplitude=0.05, width=1.0)},
            IdentificationError,
            "no design variables",
        ),
        ({"maneuver": "doublet"}, IdentificationError, "ManeuverFamily"),
        # 25 samples a second: a 13 Hz line would alias to 12 Hz
        (
            {"maneuver": Multisine("elevator", frequencies=(0.5, 13.0), amplitude=(0.0, 0.05))},
            IdentificationError,
            r"reach 13 Hz, at or above the Nyquist frequency 12.5 Hz",
        ),
        (
            {"maneuver": Chirp("elevator", f0=0.1, f1=(2.0, 12.5), amplitude=0.05)},
            IdentificationError,
            "Nyquist",
        ),
        # a 3-2-1-1 whose one-step pulses may be 0.06 s: their first null, 16.7 Hz, aliases
        (
            {"maneuver": Multistep("elevator", amplitude=0.05, width=(0.06, 1.0))},
            IdentificationError,
            r"reach 16.6667 Hz, at or above the Nyquist",
        ),
    ],
)
def test_bad_arguments_raise(kwargs, error, match):
    args = {
        "maneuver": spec_multisine(),
        "parameters": ["M_q"],
        "noise": NOISE,
        "duration": 4.0,
        "sample_rate": 25.0,
        "optimizer_options": FAST,
        **kwargs,
    }
    maneuver = args.pop("maneuver")
    parameters = args.pop("parameters")
    with pytest.raises(error, match=match):
        design_experiment(catalog.short_period(), maneuver, parameters, **args)


def test_progress_bar_does_not_change_the_design(capsys):
    kw = {
        "values": TRUTH,
        "noise": NOISE,
        "duration": 4.0,
        "sample_rate": 25.0,
        "seed": 3,
        "optimizer_options": FAST,
    }
    a = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], progress=True, **kw)
    b = design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], **kw)
    np.testing.assert_array_equal(a.controls, b.controls)
    # stderr is not a terminal under pytest, so the bar stays silent
    assert "design_experiment" not in capsys.readouterr().err


def test_a_design_that_cannot_identify_a_parameter_warns_and_is_flagged():
    # K and g enter only as their product K*g, and d not at all: no manoeuvre
    # separates K from g or tells anything about d, whatever the optimiser does.
    model = Model(
        states=["y"],
        controls=["u"],
        parameters={"K": 2.0, "g": 1.5, "tau": 0.5, "d": 1.0},
        dynamics=lambda t, x, u, p: np.array([(p["K"] * p["g"] * u[0] - x[0]) / p["tau"]]),
        name="product_lag",
    )
    with pytest.warns(aeroid.IdentifiabilityWarning) as rec:
        design = design_experiment(
            model,
            Doublet("u", amplitude=(0.1, 1.0)),
            ["K", "g", "tau", "d"],
            noise={"y": 0.01},
            duration=4.0,
            sample_rate=20.0,
            seed=1,
            optimizer_options={"maxiter": 2, "popsize": 2},
        )
    text = str(rec[0].message)
    assert "K + g" in text and "d (no sensitivity)" in text and "tau" not in text
    assert design.success is False and "cannot separate" in design.message
    for name in ("K", "g", "d"):
        assert design.predicted_stderr[name] == np.inf
    # tau is identifiable on its own: its bound stays finite
    assert np.isfinite(design.predicted_stderr["tau"])


def test_an_identifying_design_gives_no_identifiability_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", aeroid.IdentifiabilityWarning)
        design = design_experiment(
            catalog.first_order(),
            Doublet("u", amplitude=(0.1, 1.0)),
            ["K", "tau"],
            noise={"y": 0.01},
            duration=4.0,
            sample_rate=20.0,
            seed=1,
            optimizer_options={"maxiter": 2, "popsize": 2},
        )
    assert design.success is True


# -- input audit ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "culprit"),
    [
        ({"duration": "8"}, "duration and sample_rate"),
        ({"sample_rate": True}, "duration and sample_rate"),
        ({"duration": 1e12}, "samples"),
        ({"relative_step": "1e-6"}, "relative_step"),
        ({"relative_step": 0.0}, "relative_step"),
        ({"progress": "no"}, "progress"),
        ({"seed": "a"}, "seed"),
        ({"noise": {"alpha": "0.005", "q": 0.01}}, r"noise\['alpha'\]"),
        ({"optimizer_options": {"polish": "no"}}, r"optimizer_options\['polish'\]"),
        ({"optimizer_options": {"tol": "0.01"}}, r"optimizer_options\['tol'\]"),
        ({"simulate_options": {"method": "RK45", "rtol": -1.0}}, r"simulate_options\['rtol'\]"),
        (
            {
                "duration": 2000.0,
                "sample_rate": 1000.0,
                "optimizer_options": {"maxiter": 1, "popsize": 50},
            },
            "popsize",
        ),
    ],
)
def test_bad_arguments_name_the_culprit(kwargs, culprit):
    options = {"noise": NOISE, "duration": 8.0, "sample_rate": 25.0, "seed": 0}
    options["optimizer_options"] = FAST
    options.update(kwargs)  # `optimizer_options` in kwargs replaces FAST
    with pytest.raises(IdentificationError, match=culprit):
        design_experiment(catalog.short_period(), spec_multisine(), ["M_q"], **options)


def test_a_user_family_that_raises_is_named():
    """Its own exception escaped from inside the optimiser as a bare RuntimeError."""
    from aeroid import ModelDefinitionError

    class Broken:
        controls = ("elevator",)
        variable_names = ("a",)
        bounds = ((0.0, 0.05),)

        def initial(self):
            return np.array([0.02])

        def signal(self, variables, time):
            raise RuntimeError("actuator table missing")

        def describe(self, variables, time):
            return "broken"

    with pytest.raises(ModelDefinitionError, match=r"Broken: signal\(\) raised RuntimeError"):
        design_experiment(
            catalog.short_period(), Broken(), ["M_q"], values=TRUTH, noise=NOISE,
            duration=4.0, sample_rate=25.0, seed=0, optimizer_options=FAST,
        )  # fmt: skip
