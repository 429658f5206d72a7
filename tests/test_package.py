"""The package's surface: every public name resolves, and importing it stays light."""

from __future__ import annotations

import subprocess
import sys

import pytest

import aeroid


def test_every_public_name_resolves_and_is_listed():
    for name in aeroid.__all__:
        assert getattr(aeroid, name) is not None, name
    assert set(aeroid.__all__) <= set(dir(aeroid))
    with pytest.raises(AttributeError, match="no attribute 'identfy'"):
        aeroid.identfy  # noqa: B018


def test_public_names_are_the_objects_of_their_modules():
    from aeroid.estimation.identification import identify
    from aeroid.models.model import Model

    assert aeroid.identify is identify and aeroid.Model is Model
    from aeroid import FlightData, validate  # from-imports go through the same path

    assert (
        FlightData.__module__ == "aeroid.io.data"
        and validate.__module__ == "aeroid.uncertainty.validation"
    )


def test_importing_aeroid_leaves_the_heavy_modules_for_later():
    # the `aeroid` command and every spawned worker import the package; SciPy's
    # optimisers and statistics are loaded when a function that needs them is used
    code = (
        "import sys, aeroid\n"
        "heavy = [m for m in ('scipy.optimize', 'scipy.stats', 'matplotlib', 'jax') "
        "if m in sys.modules]\n"
        "print(heavy)\n"
        "aeroid.design_experiment\n"
        "print('scipy.optimize' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    first, second = out.stdout.split("\n")[:2]
    assert first == "[]"
    assert second == "True"


def test_lazy_names_match_what_type_checkers_see():
    # the names imported for type checkers and the lazy table must list the same
    # objects from the same modules, and all of them must be public
    import ast
    from pathlib import Path

    tree = ast.parse(Path(aeroid.__file__).read_text(encoding="utf-8"))
    checked = {}
    for node in tree.body:
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom)
                for alias in imp.names:
                    checked[alias.name] = "." + str(imp.module)
    assert checked == aeroid._LAZY
    assert set(aeroid._LAZY) <= set(aeroid.__all__)


def test_planning_a_campaign_loads_no_solver():
    # what an unchanged rerun, `aeroid status` and `aeroid verify` do before any task
    from pathlib import Path

    demo = Path(__file__).resolve().parents[1] / "configs" / "short_period.yaml"
    code = (
        "import sys\n"
        "from aeroid.pipeline import plan\n"
        f"p = plan({str(demo)!r})\n"
        "print(len(p.tasks), [m for m in ('scipy.integrate', 'scipy.optimize', 'scipy.stats', "
        "'matplotlib') if m in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    n, loaded = out.stdout.split(" ", 1)
    assert int(n) > 100
    assert loaded.strip() == "[]"
