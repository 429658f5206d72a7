"""A step on chosen flights only (``stages.<step>.flights``), and a design flown from a trim."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aeroid import ChannelError, IdentificationError, Model
from aeroid.errors import ConfigError
from aeroid.pipeline import plan, run
from aeroid.uncertainty.design import design_experiment
from aeroid.uncertainty.maneuvers import Doublet


def _config(tmp: Path, stages: str) -> Path:
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        "flights: [{simulated: {n_flights: 3, seed: 1, duration: 6.0}}]\n"
        "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n  validate: {}\n"
        + stages
    )
    return cfg


def test_an_optional_step_runs_on_the_flights_it_names_and_the_report_holds(tmp_path):
    cfg = _config(tmp_path, "  propagate: {n_samples: 200, flights: [sim-1]}\n")
    the_plan = plan(cfg)
    assert [t.flight for t in the_plan.tasks if t.step == "propagate"] == ["sim-1"]
    # the other flights' reports do not wait for it; the campaign report reads None there
    campaign = next(t for t in the_plan.tasks if t.step == "campaign_report")
    assert campaign.upstream["propagation"][0] is None
    assert campaign.upstream["propagation"][1] is not None
    s = run(cfg, workers=0)
    assert s.failed == 0, [st.error for st in s.statuses.values() if st.error]
    # without the option every flight runs it, with keys of their own
    every = plan(_config(tmp_path, "  propagate: {n_samples: 200}\n"))
    keys = {t.flight: t.key for t in every.tasks if t.step == "propagate"}
    assert len(keys) == 3
    chosen = next(t for t in the_plan.tasks if t.step == "propagate")
    assert keys["sim-1"] == chosen.key  # the option is the engine's, not in the key


@pytest.mark.parametrize(
    ("stages", "expected"),
    [
        ("  propagate: {flights: [sim-9]}\n", "sim-9.*not flights of the campaign"),
        ("  propagate: {flights: [sim1]}\n", "did you mean 'sim-1'"),
        ("  propagate: {flights: sim-1}\n", "stages.propagate.flights: expected a non-empty list"),
        ("  propagate: {flights: []}\n", "stages.propagate.flights: expected a non-empty list"),
        ("  validate: {flights: [sim-1]}\n", "only an optional per-flight step"),
    ],
)
def test_a_bad_selection_is_refused_naming_the_step(tmp_path, stages, expected):
    text = _config(tmp_path, "").read_text().replace("  validate: {}\n", "")
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text + (stages if "validate" in stages else "  validate: {}\n" + stages))
    with pytest.raises(ConfigError, match=expected):
        plan(cfg)


def _nonlinear(offset: float = 0.0) -> Model:
    # x' = -k x + b (u + offset)^2: the response to a small input depends on the trim
    def f(t, x, u, p):
        return np.array([-p["k"] * x[0] + p["b"] * (u[0] + offset) ** 2])

    return Model(states=["x"], controls=["u"], parameters={"k": 1.5, "b": 2.0}, dynamics=f)


def _design(model: Model, **kw) -> object:
    return design_experiment(
        model,
        Doublet("u", amplitude=(0.01, 0.2), width=(0.3, 2.0)),
        ["k", "b"],
        noise={"x": 0.01},
        duration=6.0,
        sample_rate=20.0,
        seed=3,
        optimizer_options={"maxiter": 3, "popsize": 3, "polish": False},
        **kw,
    )


def test_a_design_flown_about_a_trim_is_the_design_of_the_model_shifted_by_it():
    about = _design(_nonlinear(), trim={"u": 0.4}, x0={"x": 2.0 * 0.16 / 1.5})
    shifted = _design(_nonlinear(0.4), x0={"x": 2.0 * 0.16 / 1.5})
    assert dict(about.design) == dict(shifted.design)
    np.testing.assert_allclose(about.controls - 0.4, shifted.controls, atol=1e-15)
    np.testing.assert_allclose(about.fisher_information, shifted.fisher_information, rtol=1e-12)
    # about zero the same manoeuvre tells b apart far worse: the trim matters
    zero = _design(_nonlinear())
    assert not np.allclose(zero.fisher_information, about.fisher_information)


def test_a_bad_trim_is_refused_naming_it():
    with pytest.raises(ChannelError, match=r"trim.*'v'"):
        _design(_nonlinear(), trim={"v": 1.0})
    with pytest.raises(IdentificationError, match=r"trim.*'u'"):
        _design(_nonlinear(), trim={"u": float("nan")})


def test_the_static_margin_metric_is_the_neutral_point_distance():
    from aeroid.pipeline.stages.library_stages import METRICS

    # -Cm_alpha / CL_alpha: 0.2 chords for Cm_alpha -1, CL_alpha 5
    assert METRICS["static_margin"]({"Cm_alpha": -1.0, "CL_alpha": 5.0}) == pytest.approx(0.2)
