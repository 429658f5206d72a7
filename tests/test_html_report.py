"""The demo campaign's HTML report, rendered in headless Chromium (slow)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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

# Replaces the page body with a verdict once every image has loaded (or failed).
PROBE = """
<script>
window.addEventListener("load", () => {
  const imgs = Array.from(document.images);
  const ok = imgs.filter((i) => i.complete && i.naturalWidth > 0).length;
  const probe = document.createElement("pre");
  probe.id = "aeroid-probe";
  probe.textContent = `IMAGES ${imgs.length} LOADED ${ok}`;
  document.body.appendChild(probe);
});
</script>
"""


@pytest.fixture(scope="module")
def demo_html(tmp_path_factory):
    work = tmp_path_factory.mktemp("demo")
    config = (ROOT / "configs" / "demo.yaml").read_text(encoding="utf-8")
    config = re.sub(r"(?m)^store: .*$", f"store: {work / 'store'}", config)
    config = re.sub(r"(?m)^report: .*$", f"report: {work / 'demo.md'}", config)
    cfg = work / "demo.yaml"
    cfg.write_text(config, encoding="utf-8")
    run = subprocess.run(
        [sys.executable, "-m", "aeroid.cli", "run", str(cfg), "--json", "--quiet"],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=ROOT,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    # the demo's manoeuvres excite what every stage checks: a cold run warns of nothing
    assert "WARNING" not in run.stderr, run.stderr[-2000:]
    import json

    doc = json.loads(run.stdout)
    assert doc["report_html"] is not None
    return Path(doc["report_html"])


@pytest.mark.slow
def test_demo_html_report_embeds_at_least_six_plots(demo_html):
    html = demo_html.read_text(encoding="utf-8")
    assert html.count('src="data:image/png;base64,') >= 6
    for label in ("time histories", "bode", "posterior", "design", "estimates across flights"):
        assert label in html
    assert "<table>" in html


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (CI installs Debian's chromium)")
def test_demo_html_report_renders_its_images_in_chromium(demo_html, tmp_path):
    probe = tmp_path / "probe.html"
    probe.write_text(
        demo_html.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"),
        encoding="utf-8",
    )
    common = [CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run(
        [*common, "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    ).stdout
    found = re.search(r"IMAGES (\d+) LOADED (\d+)", dom)
    assert found, dom[-500:]
    total, loaded = int(found.group(1)), int(found.group(2))
    assert total >= 6 and loaded == total
    shot = tmp_path / "page.png"
    subprocess.run(
        [*common, f"--screenshot={shot}", "--window-size=1200,2000", demo_html.as_uri()],
        capture_output=True,
        timeout=120,
        check=False,
    )
    from matplotlib.image import imread

    pixels = imread(shot)
    assert pixels.std() > 0.05  # a rendered page, not a blank one
