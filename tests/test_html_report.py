"""The campaign report: units, a figure set per flight, honest status, and its HTML
rendered in headless Chromium (the campaign runs are slow)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aeroid._units import parameter_units
from aeroid.pipeline.stages.flight_status import LEGEND, flight_status
from aeroid.reports.html import figure_png, markdown_to_html

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
N_FLIGHTS = 3
# time histories, residual autocorrelation, held-out prediction, identification,
# filter, Bode, posterior
PER_FLIGHT = 7

# Once the page has loaded: where the first image sits (before anything is unfolded),
# then unfold every flight and wait for every image, and write the verdict.
PROBE = """
<script>
window.addEventListener("load", () => {
  const imgs = Array.from(document.images);
  const top = imgs.length ? imgs[0].getBoundingClientRect().top : -1;
  const closed = Array.from(document.querySelectorAll("details")).filter((d) => !d.open);
  const first = document.querySelector("details");
  first.open = true;
  const opened = first.querySelector("img").getBoundingClientRect().height > 0;
  for (const d of document.querySelectorAll("details")) d.open = true;
  for (const i of imgs) i.loading = "eager";
  let tries = 0;
  const verdict = () => {
    const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0).length;
    if (ok < imgs.length && tries++ < 100) return setTimeout(verdict, 50);
    const probe = document.createElement("pre");
    probe.id = "aeroid-probe";
    const right = Math.max(0, ...Array.from(document.querySelectorAll("table"))
      .map((t) => t.getBoundingClientRect().right));
    probe.textContent = `IMAGES ${imgs.length} LOADED ${ok} TOP ${top} ` +
      `HEIGHT ${window.innerHeight} CLOSED ${closed.length} OPENED ${opened} ` +
      `RIGHT ${Math.ceil(right)} WIDTH ${document.documentElement.clientWidth}`;
    document.body.appendChild(probe);
  };
  verdict();
});
</script>
"""


# -- fast: the pieces --------------------------------------------------------------------


def test_parameter_units_of_the_derivative_names():
    radians = {"alpha": "rad", "beta": "rad", "q": "rad/s", "p": "rad/s", "r": "rad/s"}
    units = parameter_units(
        ["M_alpha", "M_q", "M_delta", "Z_alpha", "Z_q", "L_p", "N_r", "Y_beta", "CL_alpha"],
        channel_units=radians,
    )
    assert units == {
        "M_alpha": "1/s²",
        "M_q": "1/s",
        "M_delta": "1/s²",
        "Z_alpha": "1/s",
        "Z_q": "-",
        "L_p": "1/s",
        "N_r": "1/s",
        "Y_beta": "1/s",
        "CL_alpha": "1/rad",  # as the aircraft models declare it
    }
    assert parameter_units(["tau_elevator", "gain"]) == {"tau_elevator": "s"}


def test_status_names_every_flag_and_the_legend_explains_each():
    ident = {
        "success": False,
        "active_bounds": {"M_q": "upper"},
        "identifiable": False,
    }
    status = flight_status(None, ident, ("q 90.0 %", "—", ("q",)), {"converged": False})
    flags = status.split("; ")
    # worst first: a poor fit or a loose estimate before a bound, coloured residuals last
    assert flags == [
        "not converged",
        "not identifiable",
        "bound M_q",
        "posterior not converged",
        "coloured 1/1",
    ]
    for word in ("not converged", "bound", "not identifiable", "coloured", "posterior"):
        assert word in LEGEND
    # fit 40 % is R² = 1 - 0.6² = 0.64; K is within two standard errors of zero and,
    # on a flight of its own, flagged as such
    loose = {
        "success": True,
        "parameters": {"K": 0.5, "tau": 2.0},
        "stderr": {"K": 0.26, "tau": 0.1},
    }
    poor = ("p 40.0 %, r 95.0 %", "—", ("p", "r"), (("p", 0.64),))
    assert flight_status(None, loose, poor, None).split("; ") == [
        "poor fit p (R² 0.64)",
        "≈ 0 K",
        "coloured 2/2",
    ]
    assert "poor fit" in LEGEND and "**≈ 0 X**" in LEGEND and "**not determined X**" in LEGEND
    clean = {"success": True, "active_bounds": {}, "identifiable": True}
    assert flight_status(None, clean, ("—", "—", ()), {"converged": True}) == "ok"
    assert flight_status("boom", clean, None, None) == "failed"
    # the data-quality flags of the channels as read: one channel named, several counted
    meta = {"quality_flags": {"q": ["jitter"], "alpha": ["jitter", "dropouts"]}}
    assert flight_status(None, clean, None, None, meta).split("; ") == [
        "data jitter (2 channels)",
        "data dropouts alpha",
    ]
    assert "**data F C**" in LEGEND


def _fit(**t_ratios: float) -> dict[str, object]:
    """A fit brief whose estimates are these many standard errors from zero."""
    return {
        "success": True,
        "parameters": {n: t * 0.01 for n, t in t_ratios.items()},
        "stderr": dict.fromkeys(t_ratios, 0.01),
    }


def test_a_flight_is_flagged_for_a_term_the_other_flights_determine():
    """|t| < 2 flags a flight only where most of the other flights tell the term from
    zero (the flight's manoeuvres fell short); a term most flights cannot tell from zero
    flags none and is named once, under Model structure."""
    from aeroid.pipeline.stages.flight_status import (
        determined_shares,
        flight_status,
        severity,
        structure_note,
    )

    # A: determined on three flights, not on the fourth; Z: zero everywhere; B: |t| = 2
    # counts as determined, 1.99 does not
    idents = [
        _fit(A=8.0, Z=0.3, B=2.0),
        _fit(A=-5.0, Z=-1.2, B=2.5),
        _fit(A=3.0, Z=1.9, B=-1.99),
        _fit(A=1.5, Z=0.0, B=4.0),
        None,  # a failed flight counts nowhere
    ]
    shares = determined_shares(idents)
    assert shares[3] == {"A": 1.0, "Z": 0.0, "B": 2.0 / 3.0}
    assert shares[2] == {"A": 2.0 / 3.0, "Z": 0.0, "B": 1.0}
    assert shares[4] is None
    status = [
        flight_status(None, r, None, None, determined=d)
        for r, d in zip(idents, shares, strict=True)
    ]
    assert status[:4] == ["ok", "ok", "not determined B", "not determined A"]
    # it ranks with the estimation flags: above a bound, a posterior, coloured residuals
    assert severity("not determined A") < severity("bound M_q") < severity("coloured 1/8")
    note = "\n".join(structure_note(idents))
    assert "Model structure" in note and "Z (4 of 4)" in note
    assert "A (" not in note and "B (" not in note
    # one flight: nothing to compare with, so a weak term is flagged "≈ 0" (low rank)
    assert determined_shares([idents[3]]) == [None]
    assert flight_status(None, idents[3], None, None) == "≈ 0 A, Z"
    assert severity("≈ 0 A") > severity("data jitter q")
    assert structure_note([idents[3]]) == []
    # a standard error that could not be computed flags nothing
    assert flight_status(None, _fit(A=1.0) | {"stderr": {"A": float("nan")}}, None, None) == "ok"


def test_the_propagated_metric_is_named_with_its_unit_where_it_is_shown():
    from aeroid.pipeline.stages._campaign_tables import metric_heading, name_the_metric

    heading = metric_heading({"propagate": {"metric": "static_margin"}}, {"static_margin": "mac"})
    assert heading == "static_margin [mac] (mean ± 1σ)"
    text = "| f | metric (mean ± std) |\n\n### Uncertainty propagation\n\n| statistic |\n"
    named = name_the_metric(text, "metric (mean ± std)", heading)
    assert "| f | static_margin [mac] (mean ± 1σ) |" in named
    assert "\n### Uncertainty propagation: static_margin [mac]\n" in named
    # a heading that merely starts so is left alone
    assert name_the_metric("## Uncertainty propagation notes", "x", heading).endswith("notes")


def test_a_filter_error_fit_is_judged_by_its_one_step_prediction():
    """A filter-error fit's poor-fit flag comes from its innovations against each
    output's measured variance (R² = 1 - ms / var), not from the open-loop simulation
    that drifts with every gust; an output-error fit keeps the simulation's."""
    from aeroid.pipeline.stages.flight_status import flight_status

    simulated_poorly = ("V 10.0 %, q 95.0 %", "—", (), (("V", 0.19),), {"V": 4.0, "q": 1.0})
    base = {"success": True, "parameters": {}, "stderr": {}}
    fe = {**base, "method": "filter_error", "residual_ms": {"V": 0.4, "q": 0.5}}
    # V: 1 - 0.4/4 = 0.9 (fine); q: 1 - 0.5/1 = 0.5 (poor)
    assert flight_status(None, fe, simulated_poorly, None) == "poor fit q (R² 0.50)"
    oe = {**base, "method": "output_error", "residual_ms": {"V": 0.4, "q": 0.5}}
    assert flight_status(None, oe, simulated_poorly, None) == "poor fit V (R² 0.19)"
    # a brief from before (no variances, no residuals) keeps the simulation's flag
    assert flight_status(None, base, simulated_poorly[:4], None) == "poor fit V (R² 0.19)"
    # the fit column says the same: 100 (1 - sqrt(ms / var)), R² = 1 - (1 - fit / 100)²
    from aeroid.pipeline.stages.flight_status import one_step_fits

    assert one_step_fits(fe, simulated_poorly) == "V 68.4 %, q 29.3 %"
    assert one_step_fits(oe, simulated_poorly) is None
    assert one_step_fits(fe, simulated_poorly[:4]) is None


def test_the_briefs_carry_measured_variances_and_residual_mean_squares():
    import numpy as np

    from aeroid.pipeline.stages._campaign_tables import fit_whiteness, residual_mean_squares

    class _Fit:
        output_names = ("a", "b")
        residuals = (np.array([[1.0, 0.0], [-1.0, 2.0]]), np.array([[3.0, 0.0]]))

    assert residual_mean_squares(_Fit()) == {"a": 11.0 / 3.0, "b": 4.0 / 3.0}

    from types import SimpleNamespace

    metric = SimpleNamespace(fit=50.0, white=True)
    valid = SimpleNamespace(
        metrics={"a": metric, "b": metric},
        output_names=("a", "b"),
        measured=np.array([[0.0, 1.0], [2.0, 1.0], [4.0, 1.0]]),
    )
    brief = fit_whiteness(valid)
    assert brief[4] == {"a": 8.0 / 3.0, "b": 0.0}
    assert brief[3] == ()  # fit 50 % is R² 0.75: not below the threshold


def test_markdown_keeps_a_fenced_block_verbatim():
    page = markdown_to_html("# T\n\n```yaml\nmodel: <x> & y\n  - a: 1\n```\n\nafter\n", {})
    assert "<pre><code>model: &lt;x&gt; &amp; y\n  - a: 1</code></pre>" in page
    assert "<p>after</p>" in page


def test_a_figure_prints_on_one_page_where_it_stays_readable():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aeroid.reports.html import figure_png, markdown_to_html

    pngs = {}
    for name, (w, h) in {"trend": (4.0, 9.6), "long": (4.0, 13.0)}.items():
        fig = plt.figure(figsize=(w, h))
        pngs[f"{name}.png"] = figure_png(fig)
        plt.close(fig)
    page = markdown_to_html("![trend](trend.png)\n\n![long](long.png)\n", pngs)
    # 2.4 high for 1 wide is scaled to a page in print; 3.25 runs on at page width
    assert '<img alt="trend" class="page"' in page
    assert '<img alt="long" loading' in page or '<img alt="long" src' in page
    assert "img.page { max-height: 9in;" in page


def test_markdown_folds_sections_and_links_anchors():
    page = markdown_to_html(
        '- [F<1>](#flight-F1)\n\n<details id="flight-F1">\n<summary>F1: ok</summary>\n\n'
        "text\n</details>\n"
    )
    assert '<li><a href="#flight-F1">F&lt;1&gt;</a></li>' in page
    assert '<details id="flight-F1">\n<summary>F1: ok</summary>\n<p>text</p>\n</details>' in page
    # anything else that looks like HTML is escaped
    assert "&lt;script&gt;" in markdown_to_html("<script>x</script>")


# -- slow: a small simulated campaign ------------------------------------------------------


def _cli(cfg: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "aeroid.cli", "run", str(cfg), "--json", "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
        check=False,
    )


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """The demo campaign cut to three flights and short chains (which do not converge)."""
    work = tmp_path_factory.mktemp("campaign")
    config = (ROOT / "configs" / "short_period.yaml").read_text(encoding="utf-8")
    config = re.sub(r"(?m)^store: .*$", f"store: {work / 'store'}", config)
    config = re.sub(r"(?m)^report: .*$", f"report: {work / 'demo.md'}", config)
    config = config.replace("n_flights: 12", f"n_flights: {N_FLIGHTS}")
    config = config.replace("n_steps: 2400", "n_steps: 300")
    config = config.replace("    priors:", "    parameters:")
    # the Bode plot's model curve: the exact transfer function linearised at the trim
    config = config.replace("    nperseg: 256", "    nperseg: 256\n    model_response: exact")
    config = config.replace("n_samples: 2000", "n_samples: 200")
    # predict the record's last quarter: the report's prediction figure and table
    config = config.replace(
        "    whiteness_lags: 20", "    whiteness_lags: 20\n    holdout: {fraction: 0.25}"
    )
    cfg = work / "demo.yaml"
    cfg.write_text(config, encoding="utf-8")
    run = _cli(cfg)
    assert run.returncode == 0, run.stderr[-2000:]
    doc = json.loads(run.stdout)
    assert doc["report_html"] is not None
    return {"config": cfg, "md": Path(doc["report"]), "html": Path(doc["report_html"])}


@pytest.mark.slow
def test_campaign_comes_first_then_a_folded_section_per_flight(campaign):
    html = campaign["html"].read_text(encoding="utf-8")
    first_img, first_table = html.index("<img"), html.index("<table>")
    assert first_img < first_table < html.index("<details")
    assert "estimates across flights" in html[first_img : first_img + 200]
    sections = re.findall(r'<details id="(flight-[^"]+)" open>(.*?)</details>', html, re.S)
    assert len(sections) == N_FLIGHTS
    for anchor, body in sections:
        assert f'href="#{anchor}"' in html
        assert body.count('src="data:image/png;base64,') == PER_FLIGHT
        assert "<table>" in body  # the flight's tables beside its figures
        for label in (
            "model outputs",
            "residuals",
            "residual autocorrelation, white-noise band",
            "prediction of the held-out manoeuvre",
            "filtered states",
            "Bode",
            "posterior",
        ):
            assert label in body
        # the prediction's metrics beside its figure, and the autocorrelation table kept
        assert "Theil U" in body and "Residual autocorrelation at lags" in body
    headers = re.search(r"<table>\n<tr>(.*?)</tr>", html).group(1)
    assert "<th>fit</th>" in headers and "<th>status</th>" in headers
    # the propagated metric by name and unit, its spread labelled 1 sigma
    assert "<th>natural_frequency [rad/s] (mean ± 1σ)</th>" in headers
    assert "<th>whiteness</th>" not in headers  # each flight's section has it
    # what was flown: the config as run, verbatim (the model, the trims, the settings)
    flown = html.split("<h2>What was flown</h2>", 1)[1].split("<h2>", 1)[0]
    config = campaign["config"].read_text(encoding="utf-8")
    from html import escape

    assert f"<pre><code>{escape(config.rstrip(chr(10)))}</code></pre>" in flown
    # the estimates transposed, each with its unit, labelled 1 sigma
    assert "± 1 standard error (1σ" in html
    # the catalog's short period declares none: guessed from the names, and marked so
    for name, unit in (
        ("Z_alpha", "1/s (guessed)"),
        ("M_alpha", "1/s² (guessed)"),
        ("M_q", "1/s (guessed)"),
        ("M_delta", "1/s² (guessed)"),
    ):
        assert f"<td>{name}</td><td>{unit}</td>" in html


@pytest.mark.slow
def test_markdown_links_its_figures_written_beside_it(campaign):
    md = campaign["md"]
    links = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", md.read_text(encoding="utf-8"))
    assert len(links) == 2 + N_FLIGHTS * PER_FLIGHT
    for rel in links:
        assert rel.startswith(f"{md.stem}_figures/")
        assert (md.parent / rel).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_status_shows_unconverged_posterior_on_a_cached_rerun_too(campaign):
    def statuses() -> list[str]:
        text = campaign["md"].read_text(encoding="utf-8")
        return re.findall(r"(?m)^- \[[^\]]+\]\(#flight-[^)]+\): (.*)$", text)

    # 300 steps are far too few: every flight's chains are flagged, not called ok
    assert statuses() == ["posterior not converged"] * N_FLIGHTS
    campaign["md"].unlink()  # the rerun rewrites it from stored records only
    again = _cli(campaign["config"])
    assert again.returncode == 0, again.stderr[-2000:]
    assert json.loads(again.stdout)["computed"] == 0
    assert statuses() == ["posterior not converged"] * N_FLIGHTS
    table = campaign["md"].read_text(encoding="utf-8")
    assert table.count("| posterior not converged |") == N_FLIGHTS


def _walk_labels(fig, units: dict[str, str]) -> list[str]:
    """Problems with the axis labels of `fig`: an unlabelled row or column, a unit missing."""
    fig.canvas.draw()
    problems = []
    axes = [ax for ax in fig.axes if ax.get_visible()]
    for ax in axes:
        box = ax.get_position()
        row = [a for a in axes if abs(a.get_position().y0 - box.y0) < 1e-6]
        col = [a for a in axes if abs(a.get_position().x0 - box.x0) < 1e-6]
        ticks_y = any(t.get_text() for t in ax.get_yticklabels())
        if ticks_y and not any(a.get_ylabel() for a in row):
            problems.append(f"no y label in the row of {ax.get_title()!r}")
        ticks_x = any(t.get_text() for t in ax.get_xticklabels())
        if (ticks_x or ax.get_xticks().size) and not any(a.get_xlabel() for a in col):
            problems.append(f"no x label in the column of {ax.get_title()!r}")
        for label in (ax.get_xlabel(), ax.get_ylabel()):
            name = label.split(" ")[0]
            if name in units and f"[{units[name]}]" not in label:
                problems.append(f"{label!r}: no unit [{units[name]}]")
    return problems


@pytest.mark.slow
def test_every_figure_labels_its_axes_with_units(campaign):
    import matplotlib.pyplot as plt

    from aeroid.pipeline import load_config, open_store, plan
    from aeroid.pipeline.stages.campaign_report import _flight_units, flight_figures
    from aeroid.reports.plotting import plot_campaign_trend

    the_plan = plan(load_config(campaign["config"]))
    store = open_store(the_plan.config.store)
    roles = {
        "load": "data",
        "identify": "identification",
        "validate": "validation",
        "filter": "filtering",
        "frequency": "frequency",
        "infer": "inference",
    }
    flight = the_plan.tasks[0].flight
    records = {
        roles[t.stage]: store.load(t.key, t.stage)
        for t in the_plan.tasks
        if t.flight == flight and t.stage in roles
    }
    assert records["frequency"].model_response == "exact"
    units = _flight_units(records)
    assert units["alpha"] == "rad" and units["M_alpha"] == "1/s²"
    assert units["sigma_q"] == "rad/s"
    figures = flight_figures(records)
    assert [label for label, _ in figures] == [
        "time_histories",
        "residual_autocorrelation",
        "prediction",
        "identification",
        "filter_states",
        "bode",
        "posterior",
    ]
    ident = records["identification"]
    trend = plot_campaign_trend(
        [
            {
                "flight": flight,
                "parameters": dict(ident.parameters),
                "stderr": dict(ident.stderr),
                "metadata": dict(records["data"].metadata),
            }
        ],
        units=units,
    )
    problems = []
    for label, fig in [*figures, ("trend", trend)]:
        problems += [f"{label}: {p}" for p in _walk_labels(fig, units)]
        plt.close(fig)
    assert not problems, problems
    # the time histories show the control input under the outputs
    assert "elevator" in figures[0][1].axes[-1].get_ylabel()


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (CI installs Debian's chromium)")
def test_html_report_renders_in_chromium_first_figure_on_screen(campaign, tmp_path):
    html = campaign["html"]
    probe = tmp_path / "probe.html"
    probe.write_text(
        html.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"),
        encoding="utf-8",
    )
    common = [CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run(
        [
            *common,
            "--window-size=1200,900",
            "--virtual-time-budget=20000",
            "--dump-dom",
            probe.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    ).stdout
    found = re.search(
        r"IMAGES (\d+) LOADED (\d+) TOP ([-\d.]+) HEIGHT (\d+) CLOSED (\d+) OPENED (\w+)", dom
    )
    assert found, dom[-500:]
    total, loaded = int(found.group(1)), int(found.group(2))
    top, height = float(found.group(3)), int(found.group(4))
    assert total == 2 + N_FLIGHTS * PER_FLIGHT and loaded == total
    assert 0 <= top < height  # the first figure is on the first screen
    assert int(found.group(5)) == 0  # every flight open, so that a printout shows it
    assert found.group(6) == "true"  # and a flight's section shows its figures
    # on an A4 page's width (794 px at 96 dpi) no table runs off the page
    page = probe.as_uri()
    narrow = subprocess.run(
        [*common, "--window-size=794,1123", "--virtual-time-budget=20000", "--dump-dom", page],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    ).stdout
    fits = re.search(r"RIGHT (\d+) WIDTH (\d+)", narrow)
    assert fits, narrow[-500:]
    assert 0 < int(fits.group(1)) <= int(fits.group(2))
    # printed (print CSS), every open flight section lays out on pages of its own
    pdf = tmp_path / "page.pdf"
    subprocess.run(
        [*common, "--no-pdf-header-footer", f"--print-to-pdf={pdf}", html.as_uri()],
        capture_output=True,
        timeout=120,
        check=False,
    )
    pages = len(re.findall(rb"/Type\s*/Page[^s]", pdf.read_bytes()))
    assert pages >= 1 + N_FLIGHTS, pages
    shot = tmp_path / "page.png"
    subprocess.run(
        [*common, f"--screenshot={shot}", "--window-size=1200,900", html.as_uri()],
        capture_output=True,
        timeout=120,
        check=False,
    )
    from matplotlib.image import imread

    pixels = imread(shot)
    assert pixels.std() > 0.05  # a rendered page, not a blank one


def test_a_filter_error_fit_is_called_coloured_by_its_innovations():
    """White innovations on one output and AR(1) ones (phi 0.8) on another: only the
    second is coloured, and the flag counts it against the fit's outputs, whatever
    the open-loop simulation's residuals say."""
    from types import SimpleNamespace

    import numpy as np

    from aeroid.pipeline.stages._campaign_tables import coloured_innovations, identification_brief
    from aeroid.pipeline.stages.flight_status import flight_status

    rng = np.random.default_rng(7)
    white = rng.normal(size=2000)
    e = rng.normal(size=2000)
    ar = np.empty(2000)
    ar[0] = e[0]
    for k in range(1, 2000):
        ar[k] = 0.8 * ar[k - 1] + e[k]
    fit = SimpleNamespace(
        parameter_names=("a",),
        parameters={"a": 1.0},
        stderr={"a": 0.1},
        method="filter_error",
        output_names=("u", "v"),
        residuals=(np.column_stack([white, ar]),),
    )
    assert coloured_innovations(fit) == ["v"]
    brief = identification_brief(fit)
    assert brief["coloured_innovations"] == ["v"]
    simulated = ("u 90.0 %, v 90.0 %", "—", ("u", "v"), (), {"u": 100.0, "v": 100.0})
    assert flight_status(None, brief, simulated, None) == "coloured 1/2"
    # an output-error fit keeps the simulation's verdict
    oe = identification_brief(SimpleNamespace(**{**vars(fit), "method": "output_error"}))
    assert "coloured_innovations" not in oe
    assert flight_status(None, oe, simulated, None) == "coloured 2/2"


@pytest.mark.slow
def test_a_term_absent_from_the_truth_is_flagged_about_as_often_as_the_test_says():
    """Fitted with a lift-from-elevator term Z_delta the truth lacks, a flight calls it
    "≈ 0" unless |t| >= 2 by chance (5 % of flights, two-sided), and never calls so the
    four terms the doublet determines."""
    import numpy as np

    import aeroid
    from aeroid.models import catalog
    from aeroid.pipeline.stages._campaign_tables import identification_brief
    from aeroid.pipeline.stages.flight_status import flight_status

    def dynamics(t, x, u, p):
        alpha, q = x
        return np.array(
            [
                p["Z_alpha"] * alpha + q + p["Z_delta"] * u[0],
                p["M_alpha"] * alpha + p["M_q"] * q + p["M_delta"] * u[0],
            ]
        )

    start = {**catalog.SHORT_PERIOD_TRUTH, "Z_delta": 0.0}
    model = aeroid.Model(
        states=["alpha", "q"], controls=["elevator"], parameters=start, dynamics=dynamics
    )
    n, flagged = 24, 0
    for seed in range(n):
        fit = aeroid.identify(model, catalog.short_period_flight(seed=100 + seed), list(start))
        status = flight_status(None, identification_brief(fit), None, None)
        assert status in ("ok", "≈ 0 Z_delta"), (seed, status)
        flagged += status == "≈ 0 Z_delta"
    # binomial(24, 0.95): at most 4 flights unflagged fails with probability under 1 %
    assert flagged >= n - 4, flagged


def _panels() -> Any:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4.0, 3.0))
    axes = fig.subplots(2, 1, sharex=True)
    t = np.linspace(0.0, 10.0, 200)
    for k, ax in enumerate(axes):
        ax.plot(t, np.sin(t + k), lw=1.0)
        ax.set_ylabel(f"q{k} [rad/s]")
        # at a fixed height, as the reports' titles: an automatic one measures the
        # panel's ticks before its axes are drawn
        ax.set_title(f"panel {k}: fit 98.{k} %", loc="left", fontsize=9, y=1.0)
    axes[-1].set_xlabel("time [s]")
    return fig


def test_kept_text_metrics_are_the_ones_matplotlib_measures():
    """The renderer `figure_png` draws with keeps each string's extent and each font's
    line height: the numbers matplotlib's own Agg renderer gives, first time and kept."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    from aeroid.reports.html import _agg_canvas

    fig = _panels()
    fig.set_dpi(72)
    ours = _agg_canvas(fig).get_renderer()
    plain = RendererAgg(*_agg_canvas(fig).get_width_height(physical=True), fig.dpi)
    texts = [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)]
    for _ in range(2):  # measured, then kept
        for text in texts:
            assert text.get_window_extent(ours).bounds == text.get_window_extent(plain).bounds
        for size, weight in ((7.0, "normal"), (10.0, "bold")):
            prop = FontProperties(size=size, weight=weight)
            for s in ("0.05", "Cm_delta_e = -1.304 ± 0.021", "lp"):
                got = ours.get_text_width_height_descent(s, prop, False)
                assert got == plain.get_text_width_height_descent(s, prop, False)


def test_ticks_are_placed_once_a_draw_and_the_figure_is_left_as_it_was(monkeypatch):
    """Each axis computes its ticks once per draw (matplotlib computes them again to
    place the axis label): the same bytes, and no trace left on the figure."""
    import contextlib

    from matplotlib.axis import Axis

    from aeroid.reports import html

    calls = []
    update = Axis._update_ticks

    def counted(self):
        calls.append(self)
        return update(self)

    monkeypatch.setattr(Axis, "_update_ticks", counted)
    fig = _panels()
    once = figure_png(fig, dpi=50)
    n_axes = 2 * len(fig.axes)
    assert len(calls) == n_axes
    assert not any(
        name in axis.__dict__
        for ax in fig.axes
        for axis in (ax.xaxis, ax.yaxis)
        for name in ("draw", "_update_ticks", "_get_ticklabel_bboxes")
    )
    calls.clear()
    monkeypatch.setattr(html, "_ticks_once_a_draw", lambda fig: contextlib.nullcontext())
    assert figure_png(fig, dpi=50) == once
    assert len(calls) > n_axes  # matplotlib's own draw: the y axes' ticks twice


def test_tick_marks_drawn_together_are_the_pixels_of_each_drawn_alone(monkeypatch):
    """`figure_png` draws an axis's tick marks in one call of the renderer: the same bytes
    as matplotlib's tick-by-tick draw, inward and outward marks, minor ticks and grid
    lines included, and a tick whose mark differs (a colour of its own) keeps its own."""
    from matplotlib.lines import Line2D

    from aeroid.reports import html

    calls = []
    draw = Line2D.draw

    def counted(self, renderer):
        calls.append(1)
        return draw(self, renderer)

    monkeypatch.setattr(Line2D, "draw", counted)

    def variants() -> list[Any]:
        plain = _panels()
        styled = _panels()
        styled.axes[0].tick_params(direction="inout", length=6, width=1.5)
        styled.axes[0].minorticks_on()
        styled.axes[1].grid(True, alpha=0.5)
        styled.axes[1].tick_params(axis="y", right=True, direction="in")
        odd = _panels()
        odd.canvas.draw()  # the ticks made, to colour one of them
        odd.axes[1].yaxis.get_major_ticks()[1].tick1line.set_markeredgecolor("r")
        return [plain, styled, odd]

    together = []
    for fig in variants():
        calls.clear()
        together.append((figure_png(fig, dpi=60), len(calls)))
    monkeypatch.setattr(html, "_plain_axis", lambda axis: False)
    for fig, (png, n_calls) in zip(variants(), together, strict=True):
        calls.clear()
        assert figure_png(fig, dpi=60) == png
        assert n_calls < len(calls)  # fewer lines drawn for the same pixels


def test_an_axis_method_set_by_its_owner_is_kept():
    """An axis whose draw its owner replaced keeps that draw after `figure_png`."""
    fig = _panels()
    axis = fig.axes[0].yaxis
    drawn = []
    own = axis.draw

    def mine(renderer):
        drawn.append(renderer)
        return own(renderer)

    axis.draw = mine
    figure_png(fig, dpi=40)
    assert axis.__dict__["draw"] is mine and len(drawn) == 1


def test_raw_html_of_another_form_is_text_and_the_conversion_ends():
    # a section id the pass-through pattern did not take looped forever (a flight named
    # 'vol_é' hung `aeroid run` after storing every result)
    from aeroid.reports.html import markdown_to_html

    out = markdown_to_html('<details id="é" open>\n</details>\ntext\n')
    assert "&lt;details id=" in out and "<p>text</p>" in out


def test_flight_anchors_are_ascii_and_distinct():
    from aeroid.pipeline.stages.campaign_report import _anchor

    names = ["vol_é", "vol_è", "vol_e", "run 1", "run_1"]
    anchors = [_anchor(n) for n in names]
    assert all(a.isascii() for a in anchors)
    assert len(set(anchors)) == len(names)
