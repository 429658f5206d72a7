"""What `aeroid run` prints and writes about a campaign: a narrow table, warnings before
it and in the report beside their flight; `verify --config` checks that config only."""

from __future__ import annotations

import re

from test_cli import invoke, make_campaign, run_json

from aeroid.cli import _TABLE_WIDTH, _narrow_table


def test_narrow_table_keeps_the_summary_columns_within_the_width():
    header = ["flight", "condition", *(f"P{k} [1/s]" for k in range(30)), "fit"]
    header += ["whiteness", "metric (mean ± std)", "status"]
    row = ["flight_01", "airspeed 45 m/s", *("-1.234 ± 0.056" for _ in range(30))]
    row += ["V 77.6 %, alpha 70.4 %, phi 60.6 %", "V coloured", "5.566 ± 0.088"]
    row += ["error > 100 % X_0, X_V, Y_0, N_0; coloured 8/8"]
    table, left_out = _narrow_table(header, [row])
    lines = table.splitlines()
    # the condition (in the report) gives way to the status, which ranks the flights
    assert left_out == 32  # the 30 estimates, the whiteness and the condition
    assert all(len(line) <= _TABLE_WIDTH for line in lines)
    assert [h.strip() for h in lines[0].split("|")[1:-1]] == ["flight", "fit", "metric", "status"]
    cells = [c.strip() for c in lines[2].split("|")[1:-1]]
    assert cells == ["flight_01", "worst phi 60.6 %", "5.566 ± 0.088", row[-1]]
    # a status too long even then is cut, but last: it keeps twice the others' widths
    row[-1] = "not determined " + ", ".join(f"X_{k}" for k in range(30))
    cells = [c.strip() for c in _narrow_table(header, [row])[0].splitlines()[2].split("|")[1:-1]]
    assert cells[3].startswith("not determined X_0, X_1") and cells[3].endswith("…")
    assert len(cells[3]) > 2 * max(len(c) for c in cells[:3])
    # a row that fits keeps its condition
    row[-1] = "ok"
    fits, n = _narrow_table(header, [row])
    assert n == 31 and "| airspeed 45 m/s |" in fits
    # a campaign that propagates nothing shows no empty metric column
    row[-2] = "—"
    empty, n = _narrow_table(header, [row])
    assert n == 32 and "metric" not in empty.splitlines()[0]
    # a narrow table (a user pipeline's) is printed whole
    small, none = _narrow_table(["flight", "mean"], [["f00", "1.5"]])
    assert none == 0 and "| f00" in small


def test_warnings_come_before_the_table_and_sit_in_their_flights_section(tmp_path):
    cfg = make_campaign(tmp_path, n=2, stats="{n_boot: 40, warn: true}")
    code, out, _ = invoke("run", str(cfg), "--workers", "0")
    assert code == 0
    lines = out.splitlines()
    warned = [i for i, x in enumerate(lines) if x.startswith("WARNING stats")]
    table = [i for i, x in enumerate(lines) if x.startswith("| ")]
    assert len(warned) == 2 and table and max(warned) < min(table)
    assert all(len(lines[i]) <= _TABLE_WIDTH for i in table)
    report = re.search(r"^report: (.*)$", out, re.M)
    assert report
    text = open(report.group(1), encoding="utf-8").read()
    for flight in ("f00", "f01"):
        section = text.split(f"<summary>{flight}: ", 1)[1].split("</details>", 1)[0]
        assert "**Warnings**" in section
        assert "- **stats**: UserWarning: only 40 bootstrap samples" in section


def test_verify_config_checks_only_that_configs_entries(tmp_path):
    cfg = make_campaign(tmp_path, n=2)
    _, doc = run_json(cfg)
    mine = len(doc["tasks"])
    # a second campaign in the same store, with other stats
    other = tmp_path / "other.yaml"
    other.write_text(cfg.read_text().replace("n_boot: 50", "n_boot: 60"))
    _, doc2 = run_json(other)
    assert doc2["computed"] >= 2
    code, out, _ = invoke("verify", "--config", str(cfg))
    assert code == 0 and f"{mine} entries checked, 0 corrupt" in out
    code, out, _ = invoke("verify", "--store", str(tmp_path / "store"))
    assert code == 0
    every = int(re.search(r"(\d+) entries checked", out).group(1))
    assert every == mine + doc2["computed"]
