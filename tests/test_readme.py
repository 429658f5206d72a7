"""The README's Python blocks run verbatim, in order, in one namespace."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from aeroid.models import catalog

README = Path(__file__).resolve().parents[1] / "README.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_has_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert 'python3 -m pip install -e ".[all,test]" && aeroid run configs/demo.yaml' in text
    ci = (README.parent / ".ci" / "run").read_text(encoding="utf-8")
    # the README's test command is what CI runs: lint and types before the tests
    (command,) = [line for line in ci.splitlines() if line.startswith("python3 -m pip install")]
    assert command.startswith('python3 -m pip install -e ".[all,test]" && ')
    assert "ruff check aeroid tests" in command and "&& mypy &&" in command
    assert command.endswith("&& python3 -m pytest -n auto")
    assert command in text


def test_readme_python_blocks_run(tmp_path, monkeypatch, capsys):
    blocks = _blocks()
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "readme"}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)
    # the README makes the flight file it loads: the truth case, as a CSV
    # (its units on a comment line, then the header)
    lines = (tmp_path / "flight_042.csv").read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("# units: ") and lines[1] == "time,elevator,alpha,q"
    result = namespace["result"]
    truth = catalog.SHORT_PERIOD_TRUTH
    for name, value in truth.items():
        est = result.parameters[name]  # type: ignore[attr-defined]
        se = result.stderr[name]  # type: ignore[attr-defined]
        assert abs(est - value) < 3 * se + 1e-12, name
    out = capsys.readouterr().out
    assert "| parameter" in out
    mc = namespace["mc"]
    assert mc.percentiles["P2.5"] < 3.0 < mc.percentiles["P97.5"]  # type: ignore[attr-defined]
    # the pipeline block: every planned key computed and stored, read back as results
    summary, plan, store = namespace["summary"], namespace["plan"], namespace["store"]
    assert summary.failed == 0 and summary.count("computed") == len(plan.tasks)  # type: ignore[attr-defined]
    assert all(store.exists(t.stage, t.key) for t in plan.tasks)  # type: ignore[attr-defined]
    fits = [store.load(e.key) for e in store.entries("identify")]  # type: ignore[attr-defined]
    assert len(fits) == 3 and all(type(f).__name__ == "IdentificationResult" for f in fits)


@pytest.mark.parametrize("block", range(len(_blocks())))
def test_readme_blocks_are_formatted(block):
    assert "\t" not in _blocks()[block]


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff not installed")
def test_the_development_commands_pass_on_the_readme_itself():
    # the README's `ruff format --check .` reads its Python blocks too
    run = subprocess.run(
        ["ruff", "format", "--check", str(README)], capture_output=True, text=True, check=False
    )
    assert run.returncode == 0, run.stdout + run.stderr


def test_every_aeroid_command_in_the_readme_exists_with_its_options():
    """The shell blocks' `aeroid ...` lines name commands and options the CLI has
    (running them all needs the demo's store: the fresh-clone walkthrough does that)."""
    import shlex

    from click.testing import CliRunner

    from aeroid.cli import main

    text = README.read_text(encoding="utf-8")
    shell = "\n".join(re.findall(r"```bash\n(.*?)```", text, flags=re.S))
    lines = [ln.split("#")[0].split("&&")[-1].strip() for ln in shell.splitlines()]
    commands = [shlex.split(ln)[1:] for ln in lines if ln.startswith("aeroid ")]
    assert len(commands) >= 9
    runner = CliRunner()
    for words in commands:
        name, options = words[0], [w for w in words[1:] if w.startswith("--")]
        assert name in main.commands, words
        helped = runner.invoke(main, [name, "--help"])
        assert helped.exit_code == 0, words
        for option in options:
            assert option in helped.output, (words, option)
