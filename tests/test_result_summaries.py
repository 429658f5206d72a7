"""Sampler runs, ensemble runs and response channels have summary() and plot(), and the
README's list of results with and without plot() holds."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.figure import Figure

import aeroid
from aeroid.models import catalog


def _cells(text: str) -> dict[str, list[str]]:
    """Rows of the first Markdown table, keyed by their first cell."""
    rows = [ln for ln in text.splitlines() if ln.startswith("|")][2:]
    out = {}
    for ln in rows:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        out[cells[0]] = cells[1:]
    return out


def test_sampler_run_summary_and_plot():
    # a standard normal in two dimensions, seeded: the draws' statistics are the table's
    start = np.random.default_rng(0).normal(size=(8, 2))
    run = aeroid.ensemble_sampler(
        lambda x: -0.5 * np.sum(x**2, axis=-1), start, 400, burn_in=100, seed=0
    )
    draws = run.chain.reshape(-1, 2)
    rows = _cells(run.summary())
    assert list(rows) == ["x[0]", "x[1]"]
    for j in range(2):
        mean, sd, lo, med, hi, r_hat, ess = rows[f"x[{j}]"]
        assert mean == f"{draws[:, j].mean():.4g}" and sd == f"{draws[:, j].std(ddof=1):.4g}"
        assert lo == f"{np.percentile(draws[:, j], 2.5):.4g}"
        assert hi == f"{np.percentile(draws[:, j], 97.5):.4g}"
        assert med == f"{np.median(draws[:, j]):.4g}"
        assert r_hat == f"{aeroid.split_r_hat(run.chain)[j]:.3f}"
        # 2400 draws of N(0, 1): the mean within 5 of its Monte Carlo errors (ESS-based)
        assert abs(draws[:, j].mean()) < 5 / np.sqrt(float(ess))
    assert "2400 draws: 8 walkers × 300 kept steps (400 steps, 100 burn-in, thin 1" in (
        run.summary()
    )
    fig = run.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 2
    assert len(fig.axes[0].lines) == 8  # one trace a walker


def test_a_one_step_sampler_run_has_no_diagnostics():
    start = np.random.default_rng(1).normal(size=(4, 1))
    run = aeroid.ensemble_sampler(lambda x: -0.5 * np.sum(x**2, axis=-1), start, 1, seed=0)
    (row,) = _cells(run.summary()).values()
    assert row[-2:] == ["—", "—"]  # R-hat and ESS need more steps


def test_ensemble_run_summary_and_plot():
    model, data = catalog.short_period(), catalog.short_period_flight(seed=1)
    priors = {"M_q": aeroid.Normal(-2.5, 1.0), "M_delta": aeroid.Normal(-9.0, 2.0)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run = aeroid.infer_ensemble(model, data, priors, n_steps=20, seed=0)
    assert isinstance(run, aeroid.EnsembleRun)
    text = run.summary()
    rows = _cells(text)
    assert list(rows) == list(run.parameter_names)
    draws = run.sampler.chain.reshape(-1, len(run.parameter_names))
    for j, name in enumerate(run.parameter_names):
        assert rows[name][0] == f"{draws[:, j].mean():.4g}"
    assert f"Ensemble 0 of model `{model.name}`." in text
    assert "aeroid.combine_ensembles" in text
    fig = run.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == len(run.parameter_names)


def test_response_channel_summary_over_the_counted_frequencies():
    w = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
    channel = aeroid.ResponseChannel(
        "elevator",
        "q",
        w,
        np.full(5, 2.0 + 0j),
        coherence=[0.2, 0.9, 0.8, 0.5, 0.1],
        random_error=[0.5, 0.05, 0.1, 0.2, 0.9],
        coherent=[False, True, True, True, False],
        mismatch=0.0412,
        dropped={"not coherent": 2},
    )
    text = channel.summary()
    assert text.startswith("## Frequency response elevator → q")
    rows = {k: v[0] for k, v in _cells(text).items()}
    assert rows["frequencies [rad/s]"] == "5: 1–16"
    assert rows["counted (`coherent`) [rad/s]"] == "3: 2–8"
    assert rows["mean γ² (counted)"] == "0.733"  # (0.9 + 0.8 + 0.5) / 3
    assert rows["mean εr [%] (counted)"] == "11.7"  # (5 + 10 + 20) / 3
    assert rows["γ² ≥ 0.6 [rad/s]"] == "2: 2–4"
    assert rows["mismatch to the model (counted)"] == "4.12%"
    assert "Not counted: 2 not coherent." in text
    unknown = aeroid.ResponseChannel("u", "y", w, np.ones(5, dtype=complex)).summary()
    assert _cells(unknown)["mean γ² (counted)"] == ["—"]
    assert _cells(unknown)["γ² ≥ 0.6 [rad/s]"] == ["—"]


@pytest.mark.parametrize(
    "cls",
    [
        "IdentificationResult",
        "ValidationResult",
        "PredictionResult",
        "FilterResult",
        "SensitivityResult",
        "RegressionResult",
        "StepwiseResult",
        "CompatibilityResult",
        "RecursiveResult",
        "SegmentationResult",
        "FrequencyResponseResult",
        "CompositeResponse",
        "ResponseChannel",
        "FrequencyDomainResult",
        "TransferFunctionFit",
        "EquivalentSystemFit",
        "BandwidthResult",
        "InferenceResult",
        "EnsembleRun",
        "SamplerRun",
        "PropagationResult",
        "ExperimentDesign",
    ],
)
def test_the_results_the_readme_lists_with_plot_have_both(cls):
    kind = getattr(aeroid, cls)
    assert callable(getattr(kind, "summary", None)) and callable(getattr(kind, "plot", None))


@pytest.mark.parametrize(
    "cls",
    [
        "FlightData",
        "DataQualityReport",
        "SimulationResult",
        "PropagationBatch",
        "Margins",
        "HandlingQualitiesLevel",
        "OrthogonalMultisine",
        "AeroDatabase",
    ],
)
def test_the_results_the_readme_lists_without_plot_have_a_summary(cls):
    kind = getattr(aeroid, cls)
    assert callable(getattr(kind, "summary", None)) and not hasattr(kind, "plot")


def test_an_identifications_summary_gives_the_units_the_report_gives():
    # declared by the model (an aircraft model: X_alpha in ft/s² with g in ft/s²),
    # guessed (and marked) from the record's channel units, none where neither knows
    from aeroid.models.aircraft import longitudinal_linear

    model = longitudinal_linear(
        V0=176.0, g=32.174, terms={"X": ["alpha"], "Z": ["alpha"], "M": ["alpha", "q"]}
    )
    t = np.arange(0.0, 10.0, 0.05)
    truth = {"X_alpha": 10.0, "Z_alpha": -1.0, "M_alpha": -4.0, "M_q": -1.5}
    # no control term: the motion from a start off trim
    sim = model.simulate(t, np.zeros((t.size, 1)), np.array([1.0, 0.05, 0.05, 0.0]), truth)
    data = aeroid.FlightData(
        t,
        {"delta_e": np.zeros(t.size), **dict(zip(model.output_names, sim.outputs.T, strict=True))},
    )
    cells = _cells(aeroid.identify(model, data, truth).summary())
    assert cells["X_alpha"][0] == "ft/s²" and cells["M_q"][0] == "1/s"

    def dynamics(t, x, u, p):
        return np.array(
            [p["Z_alpha"] * x[0] + x[1], p["M_alpha"] * x[0] + p["M_q"] * x[1] + p["k"] * u[0]]
        )

    plain = aeroid.Model(
        states=["alpha", "q"],
        controls=["elevator"],
        parameters={"M_alpha": -4.0, "M_q": -1.5, "Z_alpha": -1.0, "k": -8.0},
        dynamics=dynamics,
    )
    u = np.where((t > 1) & (t < 2), 0.02, 0.0)
    rec = plain.simulate(t, u[:, None], np.zeros(2))
    channels = {"elevator": u, "alpha": rec.outputs[:, 0], "q": rec.outputs[:, 1]}
    units = {"alpha": "rad", "q": "rad/s", "elevator": "rad"}
    fit = aeroid.identify(plain, aeroid.FlightData(t, channels, units), list(plain.parameters))
    cells = _cells(fit.summary())
    assert cells["M_alpha"][0] == "1/s² (guessed)" and cells["k"][0] == "—"
    bare = aeroid.identify(plain, aeroid.FlightData(t, channels), list(plain.parameters))
    assert "| unit" not in bare.summary()
