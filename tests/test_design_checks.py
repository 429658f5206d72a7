"""design_experiment: criteria of designs that cannot identify, failed candidates,
user families that break the protocol, bounds, delays."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeroid
from aeroid import IdentifiabilityWarning, Model
from aeroid.uncertainty.design import design_experiment
from aeroid.uncertainty.maneuvers import Doublet


def _product_roll() -> Model:
    # g and k enter only as their product: no manoeuvre separates them
    return Model(
        states=["p"],
        controls=["da"],
        parameters={"L_p": -2.0, "g": 2.0, "k": 2.5},
        dynamics=lambda t, x, u, p: np.array([p["L_p"] * x[0] + p["g"] * p["k"] * u[0]]),
        name="product_roll",
    )


@pytest.mark.parametrize("criterion", ["D", "A"])
def test_a_design_that_cannot_identify_has_an_infinite_criterion(criterion):
    # the rank-deficient information inverted through rounding gave D 6.63 and A 3.4e10,
    # and the summary read "Criterion inf -> 6.63"
    with pytest.warns(IdentifiabilityWarning):
        d = design_experiment(
            _product_roll(), Doublet("da", amplitude=(0.01, 0.1)), ["L_p", "g", "k"],
            criterion=criterion, noise={"p": 0.01}, duration=8.0, sample_rate=25.0, seed=0,
            optimizer_options={"maxiter": 3},
        )  # fmt: skip
    assert d.success is False
    assert d.criterion_value == np.inf and d.initial_criterion_value == np.inf
    # no candidate ranks above another on rounding noise: the reference design stays
    assert dict(d.design) == dict(d.initial_design)
    text = d.summary()
    assert "Criterion infinite" in text and "→" not in text


def _table_roll(raising: bool) -> Model:
    # a roll mode whose table ends at |da| = 0.0801: beyond it the dynamics return NaN
    # (or raise), as a table looked up out of range would
    def f(t, x, u, p):
        if raising and np.any(np.abs(u[0]) > 0.0801):
            raise ValueError("table out of range")
        edge = np.where(np.abs(u[0]) > 0.0801, np.nan, 0.0)
        return np.array([p["L_p"] * x[0] + p["L_da"] * u[0] + edge])

    return Model(states=["p"], controls=["da"], parameters={"L_p": -2.0, "L_da": 5.0},
                 dynamics=f, name="table_roll")  # fmt: skip


@pytest.mark.parametrize("raising", [False, True], ids=["nan", "raises"])
def test_failed_candidates_are_dropped_with_a_warning_either_way(raising):
    # NaN candidates vanished in silence and raising dynamics ended the whole design,
    # though the initial design (amplitude 0.055) flies
    with pytest.warns(UserWarning, match=r"(\d+) of (\d+) candidate designs failed") as rec:
        d = design_experiment(
            _table_roll(raising), Doublet("da", amplitude=(0.01, 0.1), width=(0.5, 2.0)),
            ["L_p", "L_da"], noise={"p": 0.01}, duration=6.0, sample_rate=10.0, seed=0,
            optimizer_options={"maxiter": 2, "popsize": 5, "polish": False},
        )  # fmt: skip
    assert 0 < d.n_failed < d.n_candidates
    assert f"{d.n_failed} of {d.n_candidates} candidate" in str(rec[0].message)
    assert f"{d.n_failed} of the {d.n_candidates} candidates failed" in d.summary()
    # the design stays where the model flies: the amplitude at most the table's edge
    assert d.success and d.design["amplitude"] <= 0.0801


def test_a_design_without_failures_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = design_experiment(
            _table_roll(False), Doublet("da", amplitude=(0.01, 0.08)), ["L_p", "L_da"],
            noise={"p": 0.01}, duration=8.0, sample_rate=25.0, seed=0,
            optimizer_options={"maxiter": 2},
        )  # fmt: skip
    assert d.n_failed == 0 and "failed" not in d.summary()


class _Sine:
    """A user's family: one amplitude of a 0.5 Hz sine on the aileron."""

    controls = ("da",)
    variable_names = ("a",)
    bounds = ((0.01, 0.1),)

    def initial(self):
        return np.array([0.05])

    def signal(self, v, t):
        return (v[0] * np.sin(2 * np.pi * 0.5 * np.asarray(t)))[:, None]

    def describe(self, v, t):
        return "sine"


def _broken(**methods) -> _Sine:
    family = _Sine()
    for name, value in methods.items():
        setattr(family, name, value)
    return family


@pytest.mark.parametrize(
    ("family", "culprit"),
    [
        # a bare numpy ValueError about concatenation
        (_broken(canonical=lambda v, t: np.array([v[0], 1.0])), r"_Sine\.canonical\(\)"),
        # these two were blamed on optimizer_options, which nobody gave
        (_broken(initial=lambda: np.array([0.05, 0.1])), r"_Sine\.initial\(\): expected 1"),
        (_broken(bounds=((0.01, np.inf),)), r"_Sine\.bounds: expected finite"),
        (_broken(bounds=((0.01, 0.1), (0.0, 1.0))), r"_Sine\.bounds: 2 bounds for 1"),
        # these two were accepted
        (_broken(initial=lambda: np.array([0.5])), r"_Sine\.initial\(\): .* outside its bounds"),
        (_broken(controls=("da", "da")), r"_Sine\.controls: 'da' is listed twice"),
    ],
    ids=["canonical", "initial_length", "inf_bound", "bounds_length", "initial_out", "dup"],
)
def test_a_user_family_that_breaks_the_protocol_is_named(family, culprit):
    roll = _table_roll(False)
    with pytest.raises(aeroid.IdentificationError, match=culprit) as info:
        design_experiment(
            roll, family, ["L_p", "L_da"], noise={"p": 0.01}, duration=4.0, sample_rate=10.0,
            seed=0, optimizer_options={"maxiter": 1, "popsize": 3},
        )  # fmt: skip
    assert "optimizer_options" not in str(info.value)


def test_a_design_at_a_fit_flies_its_estimated_time_delay():
    # the design ignored the fit's delay (tau_da = 0.3 s) that sensitivities applies:
    # its bounds were those of the undelayed manoeuvre (L_da 0.0736 against 0.0762)
    roll = _table_roll(False)
    t = np.arange(0, 10.0001, 0.02)
    da = np.where((t >= 1) & (t < 2), 0.05, 0.0) - np.where((t >= 2) & (t < 3), 0.05, 0.0)
    p = roll.simulate(t, {"da": np.interp(t - 0.3, t, da, left=0.0)}).outputs[:, 0]
    noisy = p + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    data = aeroid.FlightData(t, {"da": da, "p": noisy})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = aeroid.identify(roll, data, ["L_p", "L_da"], time_delays=["da"])
    assert fit.time_delays["da"] == pytest.approx(0.3, abs=0.05)
    family = aeroid.Chirp("da", f0=(0.05, 0.5), f1=(1.0, 4.0), amplitude=(0.01, 0.05))
    kw = {"noise": {"p": 0.01}, "duration": 4.0, "sample_rate": 25.0, "seed": 0}
    kw["optimizer_options"] = {"maxiter": 1, "popsize": 3, "polish": False}
    d = design_experiment(roll, family, ["L_p", "L_da"], values=fit, **kw)
    flown = aeroid.sensitivities(roll, d.to_flight_data(), fit, noise={"p": 0.01}, x0=[0.0])
    plain = aeroid.sensitivities(roll, d.to_flight_data(), {k: fit.parameters[k] for k in ("L_p", "L_da")},
                                 noise={"p": 0.01}, x0=[0.0])  # fmt: skip
    for name in ("L_p", "L_da"):
        assert d.predicted_stderr[name] == pytest.approx(flown.cramer_rao_bound[name], rel=1e-6)
        assert abs(plain.cramer_rao_bound[name] / flown.cramer_rao_bound[name] - 1) > 1e-3
    # the controls recorded are the commands: undelayed
    np.testing.assert_array_equal(
        d.controls[:, 0], family.signal(list(d.design.values()), d.time)[:, 0]
    )
