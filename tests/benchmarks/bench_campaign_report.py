"""The campaign report of a 24-flight demo campaign (figures for every flight).

Fresh processes, default environment: the cold campaign once, then the campaign
report alone (its entry removed, every flight cached) three times, and an
unchanged rerun; prints the report step's share of the cold run and the HTML
size. Usage: ``python tests/benchmarks/bench_campaign_report.py OUT_DIR [run options]``.
"""

from __future__ import annotations

import json
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def _run(cfg: Path, extra: list[str]) -> tuple[float, dict[str, Any]]:
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "aeroid.cli", "run", str(cfg), "--json", "--quiet", *extra],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(r.stderr[-3000:])
    return dt, json.loads(r.stdout)


def main(out: Path, extra: list[str]) -> None:
    from aeroid.pipeline import load_config, open_store, plan

    out.mkdir(parents=True, exist_ok=True)
    c = (ROOT / "configs" / "short_period.yaml").read_text(encoding="utf-8")
    c = re.sub(r"(?m)^store: .*$", f"store: {out / 'store'}", c)
    c = re.sub(r"(?m)^report: .*$", f"report: {out / 'demo.md'}", c)
    c = c.replace("n_flights: 12", "n_flights: 24").replace("    priors:", "    parameters:")
    cfg = out / "demo24.yaml"
    cfg.write_text(c, encoding="utf-8")
    cold, doc = _run(cfg, extra)
    print(f"cold campaign: {cold:.1f} s ({doc['computed']} tasks)", flush=True)
    key = plan(load_config(cfg)).report_task.key
    times = []
    for _ in range(3):
        open_store(out / "store").remove("campaign_report", key)
        Path(doc["report_html"]).unlink()
        dt, again = _run(cfg, extra)
        assert again["computed"] == 1, again["computed"]
        times.append(dt)
    unchanged, _ = _run(cfg, extra)
    report = statistics.median(times)
    size = Path(doc["report_html"]).stat().st_size / 1e6
    print(
        f"report step alone (median of 3 reruns): {report:.1f} s; unchanged rerun {unchanged:.1f} s"
    )
    print(
        f"report step / cold campaign: {(report - unchanged) / cold:.1%} (rerun overhead removed)"
    )
    print(f"HTML: {size:.2f} MB")


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2:])
