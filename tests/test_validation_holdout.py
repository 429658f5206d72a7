"""validate(holdout=...): the identified model predicts data not used in the fit."""

from __future__ import annotations

import numpy as np
import pytest
from _aircraft_data import LATERAL_LINEAR as LATERAL
from _aircraft_data import LATERAL_STATES as STATES

from aeroid import FlightData, IdentificationError, identify, validate
from aeroid.errors import IdentifiabilityWarning
from aeroid.models import catalog
from aeroid.models.aircraft import lateral_linear
from aeroid.uncertainty.prediction import prediction_metrics

SP_NOISE = {"alpha": 0.001, "q": 0.002}
LAT_NOISE = {"beta": 0.002, "p": 0.005, "r": 0.003, "phi": 0.003}


def _short_period_record(seed: int) -> FlightData:
    t = np.arange(1001) / 50.0  # 20 s: a doublet in the fitted half, another held out
    de = catalog.doublet(t, start=1.0, width=1.0, amplitude=0.05) + catalog.doublet(
        t, start=13.0, width=0.7, amplitude=-0.04
    )
    return catalog.short_period_flight(
        duration=20.0, sample_rate=50.0, seed=seed, elevator=de, noise=SP_NOISE
    )


def _lateral_record(seed: int) -> tuple[object, FlightData]:
    model = lateral_linear(V0=60.0, parameters=LATERAL, outputs=STATES)
    t = np.arange(1001) / 50.0
    da = catalog.doublet(t, start=1.0, width=1.0, amplitude=0.03) + catalog.doublet(
        t, start=12.0, width=0.8, amplitude=-0.02
    )
    dr = catalog.doublet(t, start=5.0, width=1.0, amplitude=0.05) + catalog.doublet(
        t, start=15.0, width=1.2, amplitude=0.04
    )
    sim = model.simulate(t, np.column_stack([da, dr]), method="exact")
    rng = np.random.default_rng(seed)
    channels = {"delta_a": da, "delta_r": dr}
    for name, sd in LAT_NOISE.items():
        channels[name] = sim.output(name) + sd * rng.standard_normal(t.size)
    return model, FlightData(t, channels, {})


def test_metrics_closed_form():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    y_hat = np.array([1.0, 2.0, 3.0, 3.0])
    m = prediction_metrics(y, y_hat)
    assert m.rmse == pytest.approx(0.5)
    # Theil U = rms(e) / (rms(y) + rms(y_hat))
    assert m.theil_u == pytest.approx(0.5 / (np.sqrt(30 / 4) + np.sqrt(23 / 4)))
    assert m.r_squared == pytest.approx(1.0 - 1.0 / 5.0)  # sum (y - 2.5)^2 = 5
    assert m.fit == pytest.approx(100.0 * (1.0 - np.sqrt(1.0 / 5.0)))
    perfect = prediction_metrics(y, y)
    assert (perfect.rmse, perfect.theil_u, perfect.r_squared, perfect.fit) == (0.0, 0.0, 1.0, 100.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_short_period_fit_on_one_window_predicts_the_held_out_window(seed):
    data = _short_period_record(seed)
    sp = catalog.short_period()
    fit = identify(sp, data.window(0.0, 10.0), list(catalog.SHORT_PERIOD_TRUTH))
    v = validate(catalog.short_period(), data, fit, holdout={"t0": 10.0, "t1": 20.0})
    pred = v.prediction
    assert pred is not None and pred.source == "window [10, 20] s"
    assert pred.time[0] >= 10.0 and pred.time[-1] == pytest.approx(20.0)
    for name in ("alpha", "q"):
        m = pred.metrics[name]
        assert m.r_squared > 0.95, (name, m)
        assert m.theil_u < 0.15, (name, m)
        # a right model's prediction error is the noise: 500 samples put the
        # sample RMS within a few % of sigma, parameter error adds a little
        assert 0.85 < m.rmse / SP_NOISE[name] < 1.3, (name, m)
    # a wrong model (control derivative of the other sign's magnitude) predicts badly
    wrong = {**dict(fit.parameters), "M_delta": 0.3 * fit.parameters["M_delta"]}
    bad = validate(catalog.short_period(), data, wrong, holdout={"t0": 10.0, "t1": 20.0})
    assert bad.prediction is not None
    assert bad.prediction.metrics["q"].r_squared < 0.6
    assert bad.prediction.metrics["q"].theil_u > 2 * pred.metrics["q"].theil_u


def test_lateral_fit_predicts_the_last_fraction_and_a_second_record():
    model, data = _lateral_record(seed=4)
    start = lateral_linear(
        V0=60.0, parameters={k: 0.7 * v for k, v in LATERAL.items()}, outputs=STATES
    )
    fit = identify(start, data.window(0.0, 10.0), list(LATERAL))
    v = validate(model, data, fit, holdout={"fraction": 0.5})
    assert v.prediction is not None
    assert v.prediction.time[0] == pytest.approx(10.0)
    for name in STATES:
        m = v.prediction.metrics[name]
        assert m.r_squared > 0.9 and m.theil_u < 0.15, (name, m)
        assert 0.85 < m.rmse / LAT_NOISE[name] < 1.3, (name, m)
    _, other = _lateral_record(seed=5)  # another manoeuvre flown with the same inputs
    second = validate(model, data, fit, holdout=other)
    assert second.prediction is not None and second.prediction.source == "second record"
    assert second.prediction.metrics["p"].r_squared > 0.9
    wrong = {**dict(fit.parameters), "L_p": -0.5, "N_r": 0.3}  # little roll damping, unstable yaw
    bad = validate(model, data, wrong, holdout={"fraction": 0.5})
    assert bad.prediction is not None
    assert bad.prediction.metrics["p"].r_squared < 0.5


def test_prediction_is_stored_read_only_and_summarised():
    data = _short_period_record(0)
    v = validate(
        catalog.short_period(catalog.SHORT_PERIOD_TRUTH), data, None, holdout={"fraction": 0.3}
    )
    assert v.prediction is not None
    with pytest.raises(ValueError):
        v.prediction.predicted[0, 0] = 1.0
    text = v.summary()
    assert "Theil U" in text and "R^2" in text and "held-out" in text
    assert validate(catalog.short_period(), data).prediction is None


@pytest.mark.parametrize(
    ("holdout", "culprit"),
    [
        ({"t0": 15.0, "t1": 25.0}, "outside the record"),
        ({"t0": -1.0, "t1": 5.0}, "outside the record"),
        ({"t0": 5.0, "t1": 5.1}, "at least 10"),
        ({"t0": 5.0, "t1": 4.0}, "t1 > t0"),
        ({"t0": 5.0}, "holdout.t1"),
        ({"fraction": 1.5}, "holdout.fraction"),
        ({"fraction": 0.001}, "at least 10"),
        ({"fraction": 0.2, "t0": 1.0}, "not both"),
        ({"start": 1.0}, "unknown key"),
        ({"t0": "a", "t1": 5.0}, "holdout.t0"),
        ([1.0, 2.0], "holdout: expected"),
    ],
)
def test_bad_holdout_is_refused_naming_the_option(holdout, culprit):
    data = _short_period_record(0)
    with pytest.raises(IdentificationError, match="holdout") as err:
        validate(catalog.short_period(), data, holdout=holdout)
    assert culprit in str(err.value)


def test_too_short_second_record_is_refused():
    data = _short_period_record(0)
    with pytest.raises(IdentificationError, match="holdout: the held-out record has 5 samples"):
        validate(catalog.short_period(), data, holdout=data.window(0.0, 0.09))


def test_a_window_of_the_fitted_record_is_marked_as_no_independent_check():
    data = _short_period_record(1)
    names = list(catalog.SHORT_PERIOD_TRUTH)
    whole = identify(catalog.short_period(), data, names)
    v = validate(catalog.short_period(), data, whole, holdout={"fraction": 0.4})
    assert v.prediction is not None and v.prediction.in_fit
    assert "no independent check" in v.summary()
    part = identify(catalog.short_period(), data.window(0.0, 10.0), names)
    held = validate(catalog.short_period(), data, part, holdout={"fraction": 0.4})
    assert held.prediction is not None and not held.prediction.in_fit
    assert "no independent check" not in held.summary()


def test_an_unexcited_held_out_window_warns_and_is_marked():
    # the default record's doublet ends at 3 s: 12-20 s is the trim and noise
    data = catalog.short_period_flight(duration=20.0, seed=3)
    truth = catalog.short_period(catalog.SHORT_PERIOD_TRUTH)
    with pytest.warns(IdentifiabilityWarning, match=r"held-out data \(window \[12, 20\] s\)"):
        v = validate(truth, data, None, holdout={"t0": 12.0, "t1": 20.0})
    assert v.prediction is not None and not v.prediction.excited
    assert all(r < np.sqrt(2.0) for r in v.prediction.response_to_noise.values())
    assert "Not excited" in v.summary()
    excited = validate(truth, _short_period_record(0), None, holdout={"t0": 10.0, "t1": 20.0})
    assert excited.prediction is not None and excited.prediction.excited


def test_the_validate_stage_takes_a_held_out_window_or_fraction():
    from pydantic import ValidationError

    from aeroid.pipeline.stages.library_stages import ValidateOptions

    opts = ValidateOptions(holdout={"t0": 12.0, "t1": 20.0})
    assert opts.library_kwargs() == {"holdout": {"t0": 12.0, "t1": 20.0}}
    assert ValidateOptions(holdout={"fraction": 0.25}).library_kwargs() == {
        "holdout": {"fraction": 0.25}
    }
    assert ValidateOptions().library_kwargs() == {}
    for bad, says in (
        ({"t0": 1.0}, "needs both t0 and t1"),
        ({"t0": 2.0, "t1": 1.0}, "t1 > t0"),
        ({"fraction": 0.2, "t1": 3.0}, "not both"),
        ({"fraction": 1.2}, "fraction"),
        ({"start": 1.0}, "start"),
        ({}, "give t0 and t1"),
    ):
        with pytest.raises(ValidationError, match=says):
            ValidateOptions(holdout=bad)


def test_a_campaign_config_with_a_bad_holdout_names_the_option(tmp_path):
    from pathlib import Path

    from aeroid.errors import ConfigError
    from aeroid.pipeline import load_config, plan

    root = Path(__file__).resolve().parents[1] / "configs"
    text = (root / "short_period.yaml").read_text(encoding="utf-8")
    assert "    whiteness_lags: 20\n" in text
    text = text.replace(
        "    whiteness_lags: 20\n", "    whiteness_lags: 20\n    holdout: {t0: 5.0}\n"
    )
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text.replace("store: ", f"store: {tmp_path}/store #"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"stages\.validate\.holdout: .*needs both t0 and t1"):
        plan(load_config(cfg))


def test_the_fits_output_bias_applies_on_a_window_of_its_record_only():
    data = _short_period_record(2)
    offset = 0.01  # a sensor bias on alpha, estimated by the fit
    biased = data.with_channels({"alpha": data["alpha"] + offset})
    names = list(catalog.SHORT_PERIOD_TRUTH)
    fit = identify(catalog.short_period(), biased, names, estimate_bias=["alpha"])
    window = validate(catalog.short_period(), biased, fit, holdout={"fraction": 0.5})
    assert window.prediction is not None
    n = window.prediction.time.size
    miss = window.prediction.measured[:, 0] - window.prediction.predicted[:, 0]
    # the bias removed: the mean error within 4 standard errors of the noise
    assert abs(miss.mean()) < 4 * SP_NOISE["alpha"] / np.sqrt(n)
    # a second record (another fingerprint) starts without the fit's biases
    other = FlightData(biased.time + 100.0, dict(biased.channels), dict(biased.units))
    second = validate(catalog.short_period(), biased, fit, holdout=other)
    assert second.prediction is not None
    gap = second.prediction.measured[:, 0] - second.prediction.predicted[:, 0]
    # (less the start's transient: the measured alpha(0) it starts from holds the offset)
    assert 0.8 * offset < gap.mean() < offset + 4 * SP_NOISE["alpha"] / np.sqrt(gap.size)


def test_a_campaign_holds_the_window_out_of_the_fit_and_predicts_it(tmp_path):
    from aeroid.pipeline import open_store, plan, run

    def config(identify: str, store: str) -> object:
        cfg = tmp_path / f"{store}.yaml"
        cfg.write_text(
            f"model: short_period\nseed: 5\nstore: {store}\nreport: out/{store}.md\n"
            "flights: [{simulated: {n_flights: 2, seed: 1, duration: 20.0, "
            "maneuver: doublet_sweep}}]\n"
            f"stages:\n  identify: {{parameters: [Z_alpha, M_alpha, M_q, M_delta]{identify}}}\n"
            "  validate: {holdout: {t0: 12.0, t1: 16.0}}\n"
        )
        return cfg

    def results(cfg: object, store: str) -> dict[str, dict[str, object]]:
        s = run(cfg, workers=0)
        assert s.failed == 0, [st.error for st in s.statuses.values() if st.error]
        st = open_store(tmp_path / store)
        out: dict[str, dict[str, object]] = {}
        for t in s.plan.tasks:
            if t.step in ("identify", "validate"):
                out.setdefault(t.flight, {})[t.step] = st.load(t.key, t.stage)
        return out

    plain_cfg = config("", "plain")
    held_cfg = config(", holdout: {t0: 12.0, t1: 16.0}", "held")
    # without the option the identify keys are those of earlier releases
    plain_keys = {t.key for t in plan(plain_cfg).tasks if t.step == "identify"}
    assert not plain_keys & {t.key for t in plan(held_cfg).tasks if t.step == "identify"}
    inside, outside = results(plain_cfg, "plain"), results(held_cfg, "held")
    for flight, rec in outside.items():
        # fitted on the two parts either side of the window, records of their own
        assert len(rec["identify"].data_fingerprints) == 2
        held, seen = rec["validate"].prediction, inside[flight]["validate"].prediction
        assert not held.in_fit and seen.in_fit
        # the window is a small part of the data: the fits and predictions hardly differ
        for name, m in held.metrics.items():
            assert abs(m.rmse - seen.metrics[name].rmse) < 0.1 * seen.metrics[name].rmse
    # a window that leaves nothing to fit on fails the flight's fit, naming the option
    bad = run(config(", holdout: {t0: 0.0, t1: 19.95}", "bad"), workers=0)
    errors = [st.error for st in bad.statuses.values() if st.error]
    assert bad.failed and any("stages.identify.holdout" in e for e in errors), errors
