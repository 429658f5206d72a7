"""report: sections, interpretation and byte-for-byte determinism."""

from __future__ import annotations

import math
import os
import stat

import pytest

from aeroid import OutputError, identify, propagate, report, validate
from aeroid.models import catalog


def _chain():
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    r = identify(model, data, list(catalog.SHORT_PERIOD_TRUTH))
    v = validate(model, data, r)
    mc = propagate(
        r, lambda p: math.sqrt(p["M_q"] * p["Z_alpha"] - p["M_alpha"]), n_samples=500, seed=0
    )
    return v, r, mc


def test_report_is_deterministic_and_complete(tmp_path):
    v, r, mc = _chain()
    a = report(v, r, mc, title="Flight 7")
    b = report(*_chain(), title="Flight 7")
    assert a == b  # trap 12f: no wall-clock date unless asked for
    for heading in (
        "# Flight 7",
        "## Identification",
        "## Validation",
        "## Uncertainty propagation",
    ):
        assert heading in a
    assert "fit" in a and "Date:" not in a
    assert "Date: 2026-01-01" in report(v, r, mc, date="2026-01-01")
    path = tmp_path / "sub" / "report.md"
    text = report(v, r, mc, title="Flight 7", path=path, figures=False)
    assert path.read_text(encoding="utf-8") == text == a
    assert [p.name for p in path.parent.iterdir()] == ["report.md"]  # no temporaries left


def test_report_with_figures_writes_pngs_and_self_contained_html(tmp_path):
    v, r, mc = _chain()
    first = tmp_path / "one" / "flight.md"
    second = tmp_path / "two" / "flight.md"
    text = report(v, r, mc, path=first)
    report(*_chain(), path=second)
    pngs = sorted(p.name for p in (first.parent / "flight_figures").iterdir())
    assert pngs == [
        "identification.png",
        "propagation.png",
        "residual_autocorrelation.png",
        "time_histories.png",
    ]
    assert "![time_histories](flight_figures/time_histories.png)" in text
    html = first.with_suffix(".html").read_text(encoding="utf-8")
    assert html.count('src="data:image/png;base64,') == 4 and "<table>" in html
    # identical inputs give identical bytes, images included
    assert first.with_suffix(".html").read_bytes() == second.with_suffix(".html").read_bytes()
    assert not [p for p in first.parent.iterdir() if p.name.startswith(".tmp")]
    # written with the permissions any new file gets here, not private ones
    mask = os.umask(0)
    os.umask(mask)
    for p in (first, first.with_suffix(".html"), first.parent / "flight_figures" / pngs[0]):
        assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~mask


def test_a_report_path_that_cannot_be_written_is_an_output_error(tmp_path):
    (tmp_path / "afile").write_text("")
    with pytest.raises(OutputError, match=r"cannot write .*afile/r.md"):
        report(*_chain(), path=tmp_path / "afile" / "r.md", figures=False)
    with pytest.raises(OutputError, match=r"cannot write .*: it is a directory"):
        report(*_chain(), path=tmp_path, figures=False)


def test_empty_report_says_so():
    assert "No results" in report()


def test_each_section_heading_appears_once():
    # frequency, sensitivity and design summaries open with their own heading; in the
    # report the section gives it, so none appears twice
    from aeroid import frequency_response, sensitivities

    v, r, mc = _chain()
    model = catalog.short_period()
    data = catalog.short_period_flight(seed=0)
    freq = frequency_response(model, data, r, frequency_range=(0.2, 3.0), min_coherent=1)
    sens = sensitivities(model, data, ["M_q"], values=r, noise={"alpha": 0.005, "q": 0.01})
    assert freq.summary().startswith("## ")  # standalone, a summary keeps its heading
    text = report(v, r, mc, frequency=freq, sensitivity=sens)
    headings = [line for line in text.splitlines() if line.startswith("#")]
    assert len(headings) == len(set(headings))
    assert "## Frequency response" in headings and "## Sensitivities" in headings
    assert not any("Sensitivity analysis" in h for h in headings)


def test_markdown_to_html_covers_what_the_reports_write():
    from aeroid.reports.html import markdown_to_html

    png = b"\x89PNG\r\n\x1a\nfake"
    text = (
        "# Campaign <A>\n\nA **bold** word and `c<1>` code,\nwrapped.\n\n"
        "| flight | **M_q** |\n|---|:--:|\n| `sim-0` | -2 ± 0.1 |\n\n"
        "- one **item**\n- two\n\n![trend](fig0)\n![missing](other.png)\n"
    )
    html = markdown_to_html(text, {"fig0": png})
    assert "<title>Campaign &lt;A&gt;</title>" in html
    assert "<h1>Campaign &lt;A&gt;</h1>" in html
    assert "<p>A <strong>bold</strong> word and <code>c&lt;1&gt;</code> code, wrapped.</p>" in html
    assert "<tr><th>flight</th><th><strong>M_q</strong></th></tr>" in html
    assert "<tr><td><code>sim-0</code></td><td>-2 ± 0.1</td></tr>" in html
    assert "---" not in html  # the alignment row is not a row
    assert "<ul><li>one <strong>item</strong></li><li>two</li></ul>" in html
    assert '<img alt="trend" src="data:image/png;base64,iVBORw0KGgpmYWtl">' in html
    assert '<img alt="missing" src="other.png">' in html


def test_report_shows_correlations_and_residual_autocorrelation_with_its_band():
    import numpy as np

    from aeroid import identify, validate
    from aeroid.models import catalog
    from aeroid.reports.reporting import report_sections

    model = catalog.short_period()
    data = catalog.short_period_flight(seed=3)
    fit = identify(model, data, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
    val = validate(model, data, fit)
    text = dict(report_sections(val, fit))
    ident, valid = text["Identification"], text["Validation"]
    assert "Parameter correlation matrix:" in ident
    c = np.asarray(fit.correlation)
    i, j = fit.parameter_names.index("M_q"), fit.parameter_names.index("M_alpha")
    matrix = ident.split("Parameter correlation matrix:", 1)[1]
    row = next(ln for ln in matrix.splitlines() if ln.startswith("| M_q "))
    assert f"{c[i, j]:+.2f}" in row and "+1.00" in row  # lower triangle, unit diagonal
    # lag-1 autocorrelation of alpha's residuals and the band 1.96/sqrt(N)
    n = val.residuals.shape[0]
    e = val.residuals[:, 0] - val.residuals[:, 0].mean()
    r1 = float(np.dot(e[:-1], e[1:]) / np.dot(e, e))
    assert f"±{1.96 / np.sqrt(n):.3f}" in valid
    band = valid.split("Residual autocorrelation", 1)[1]
    row = next(ln for ln in band.splitlines() if ln.startswith(f"| {val.output_names[0]} "))
    assert row.split("|")[2].strip() == f"{r1:+.2f}"


def test_report_tables_of_estimates_residuals_and_innovations_carry_units():
    from aeroid import filter_states, identify, validate
    from aeroid.models import catalog
    from aeroid.reports.reporting import report_sections

    model = catalog.short_period()
    data = catalog.short_period_flight(seed=3)
    fit = identify(model, data, ["Z_alpha", "M_alpha", "M_q", "M_delta"])
    val = validate(model, data, fit)
    filt = filter_states(
        model,
        data,
        fit,
        process_noise={"alpha": 1e-8, "q": 1e-8},
        measurement_noise={"alpha": 0.005**2, "q": 0.01**2},
    )
    text = dict(report_sections(val, fit, filtering=filt))

    def unit_of(body: str, header_word: str, row: str) -> str:
        lines = body.splitlines()
        at = next(k for k, ln in enumerate(lines) if ln.startswith("|") and header_word in ln)
        head, table = lines[at], lines[at:]
        assert [c.strip() for c in head.split("|")][2] == "unit"
        line = next(ln for ln in table if ln.startswith(f"| {row} "))
        return line.split("|")[2].strip()

    # the catalog model declares no units: guessed from the names, and marked so
    assert unit_of(text["Identification"], "estimate", "M_alpha") == "1/s² (guessed)"
    assert unit_of(text["Identification"], "estimate", "M_q") == "1/s (guessed)"
    assert unit_of(text["Validation"], "RMSE", "alpha") == data.units["alpha"]
    assert unit_of(text["Validation"], "RMSE", "q") == data.units["q"]
    assert unit_of(text["State estimation"], "innovation", "q") == data.units["q"]
    # the states' standard deviations too (filtered here; smoothed ones alike)
    assert unit_of(text["State estimation"], "max std", "alpha") == data.units["alpha"]


def test_a_wrong_argument_is_named_before_any_is_read():
    from aeroid.errors import AeroidError

    with pytest.raises(AeroidError, match="the validation argument is not a result"):
        report(42)
    with pytest.raises(AeroidError, match="the inference argument is not a result"):
        report(inference="posterior")
    with pytest.raises(OutputError, match="path must be a file path, got int"):
        report(None, path=5)  # type: ignore[arg-type]


def test_a_result_in_another_slot_is_named(sp_noisy):
    """A fit passed first (where the validation goes) raised AttributeError from deep in
    the notes; passed third it rendered as an "Uncertainty propagation" section."""
    from aeroid.errors import AeroidError

    model = catalog.short_period()
    fit = identify(model, sp_noisy, list(catalog.SHORT_PERIOD_TRUTH))
    with pytest.raises(AeroidError, match=r"validation argument \(IdentificationResult\)"):
        report(fit)
    with pytest.raises(AeroidError, match="propagation argument"):
        report(None, None, fit)
    with pytest.raises(AeroidError, match="experiment argument"):
        report(experiment=fit)
    assert "## Identification" in report(None, fit)


def test_vector_propagation_reports_and_plots(sp_noisy):
    model = catalog.short_period()
    fit = identify(model, sp_noisy, list(catalog.SHORT_PERIOD_TRUTH))
    several = propagate(
        fit, lambda p: {"wn": p["M_q"], "d": 2.0 * p["M_alpha"]}, n_samples=200, seed=0
    )
    text = report(propagation=several)
    assert "| wn " in text and "| d " in text
    fig = several.plot()
    assert len(fig.axes) == 2


def test_a_failed_bundle_leaves_no_figures_behind(tmp_path, sp_noisy):
    model = catalog.short_period()
    fit = identify(model, sp_noisy, list(catalog.SHORT_PERIOD_TRUTH))
    (tmp_path / "d").mkdir()
    with pytest.raises(OutputError, match="is a directory"):
        report(None, fit, path=tmp_path / "d")
    (tmp_path / "r.html").mkdir()
    with pytest.raises(OutputError, match=r"r\.html: it is a directory"):
        report(None, fit, path=tmp_path / "r.md")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d", "r.html"]


def test_parameters_the_data_cannot_separate_have_no_correlation_printed():
    """A gain a*b: a and b are one direction. The matrix printed +0.00 for the pair."""
    import warnings

    import numpy as np

    import aeroid

    def f(t, x, u, p):
        return np.array([p["L_p"] * x[0] + p["a"] * p["b"] * u[0]])

    model = aeroid.Model(["p"], ["da"], {"L_p": -1.0, "a": 2.0, "b": 3.0}, f)
    t = np.arange(0.0, 5.0, 0.02)
    u = np.where((t > 1) & (t < 2), 1.0, 0.0)
    truth = {"L_p": -2.0, "a": 2.0, "b": 5.0}
    data = model.simulate(t, u, [0.0], truth).to_flight_data(noise={"p": 0.01}, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit = identify(model, data, ["L_p", "a", "b"])
    assert not fit.identifiable
    assert np.isnan(fit.correlation[1, 2]) and fit.correlation[1, 1] == 1.0
    text = report(identification=fit)
    row = next(line for line in text.splitlines() if line.startswith("| b "))
    assert "—" in row and "+0.00" not in row
