"""Issue 49, careless configs: paths that cannot be used as written are refused by key
before anything runs (the store's own checks live in test_hostile_inputs.py)."""

from __future__ import annotations

import pytest

from aeroid.errors import ConfigError
from aeroid.pipeline.plans.config import load_config


def _config(tmp_path, extra: str):
    (tmp_path / "a.csv").write_text("time,q\n0,1\n0.1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: [a.csv]\n" + extra)
    return cfg


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        # made a folder literally named '$OUT' beside the config
        ("report: $OUT/r.md\n", r"c\.yaml: report: '\$OUT/r\.md' names an environment variable"),
        ("report: '%TEMP%/r.md'\n", r"report: .* names an environment variable"),
        # a raw RuntimeError from pathlib
        ("store: ~no-such-user-j49s/s\n", r"store: .* home folder of a user this machine"),
        ("report: ~no-such-user-j49s/r.md\n", r"report: .* home folder of a user"),
    ],
)
def test_a_path_that_cannot_be_used_as_written_is_refused_by_key(tmp_path, extra, match):
    with pytest.raises(ConfigError, match=match):
        load_config(_config(tmp_path, extra))


def test_the_home_folder_and_plain_paths_are_still_taken(tmp_path):
    cfg = load_config(_config(tmp_path, "store: ~/aeroid-store\nreport: out/r.md\n"))
    assert cfg.store_location.endswith("aeroid-store") and "~" not in cfg.store_location
    assert cfg.report_path == tmp_path / "out" / "r.md"


@pytest.mark.parametrize(
    ("counts", "refused"),
    [
        ("n_walkers: 100000, n_steps: 10000000", True),  # each within its own bound
        ("n_steps: 10000000, n_ensembles: 1000", True),  # even at the fewest walkers
        ("n_walkers: 64, n_steps: 100000, n_ensembles: 4", False),
    ],
)
def test_infer_counts_whose_product_cannot_finish_are_refused_at_check(tmp_path, counts, refused):
    from aeroid.pipeline.plans.checks import preflight

    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [{simulated: {n_flights: 1}}]\nstages:\n"
        "  identify: {parameters: [M_alpha, M_q]}\n"
        f"  infer: {{parameters: {{M_q: {{normal: [0, 1]}}}}, {counts}}}\n"
    )
    if not refused:
        preflight(cfg)
        return
    with pytest.raises(ConfigError, match=r"stages\.infer: n_walkers x n_steps x n_ensembles"):
        preflight(cfg)


@pytest.mark.parametrize("command", ["verify", "gc"])
def test_a_store_under_an_unknown_users_home_is_refused_by_the_cli(command: str) -> None:
    import subprocess
    import sys

    code = "from aeroid.cli import main; main()"
    done = subprocess.run(
        [sys.executable, "-c", code, command, "--store", "~nosuchuser_aeroid/x"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert "no home folder for 'nosuchuser_aeroid'" in done.stderr
    assert "Traceback" not in done.stderr


def test_an_existing_file_with_glob_characters_is_the_flight_named(tmp_path):
    # 'run[1].csv' was read as a pattern: it matched run1.csv (another flight, fitted in
    # its place) or, alone, "matches no file"
    for name in ("run[1].csv", "run1.csv"):
        (tmp_path / name).write_text("time,q\n0,1\n0.1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: ['run[1].csv']\n")
    files = [path.name for _, path, _ in load_config(cfg).expand_files()]
    assert files == ["run[1].csv"]
    (tmp_path / "run1.csv").unlink()
    assert [p.name for _, p, _ in load_config(cfg).expand_files()] == ["run[1].csv"]
    cfg.write_text("model: short_period\nflights: ['run[0-9].csv']\n")  # still a pattern
    with pytest.raises(ConfigError, match="matches no file"):
        load_config(cfg).expand_files()
