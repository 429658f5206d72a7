"""The house rules, read from the source: no import cycles, no private names
crossing from one package into another.

The import graph is built with `ast` from every ``import`` in every module,
function-local ones included, because a cycle hidden inside a function still
ties the two modules together.  Imports under ``if TYPE_CHECKING:`` are left
out: they never run.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1] / "aeroid"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _runtime_imports(tree: ast.AST) -> Iterator[ast.Import | ast.ImportFrom]:
    """Every import statement that can run, however deeply nested."""
    stack: list[ast.AST] = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def _base(module: str, path: Path, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    if node.level > 1:
        package = package[: len(package) - node.level + 1]
    return ".".join([*package, *([node.module] if node.module else [])])


def _edges(
    modules: dict[str, Path],
) -> Iterator[tuple[str, str, str]]:
    """(importer, imported module, imported name) for every in-package import."""
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in _runtime_imports(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name in modules:
                        yield module, alias.name, ""
                continue
            base = _base(module, path, node)
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                if submodule in modules:
                    yield module, submodule, ""
                elif base in modules:
                    yield module, base, alias.name


def import_graph() -> dict[str, set[str]]:
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for importer, imported, _ in _edges(modules):
        if imported != importer:
            graph[importer].add(imported)
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def _package(module: str, modules: dict[str, Path]) -> str:
    if modules[module].name == "__init__.py":
        return module
    return module.rsplit(".", 1)[0]


# the engine and the adapters reach the library's private helpers only through
# `aeroid.support`; the library's own rooms share the leaves of `aeroid/`
_APART = ("aeroid.pipeline", "aeroid.adapters")


def _sees(importer: str, owner: str) -> bool:
    """Whether package `importer` may use the private names of package `owner`: its own,
    and those of a package above it; but the engine and the adapters see none of the
    library's (the engine's seams do see the vocabulary they share, in aeroid/pipeline)."""
    if importer == owner:
        return True
    if not importer.startswith(owner + "."):
        return False
    return not importer.startswith(_APART) or owner.startswith(_APART)


def _private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def private_crossings() -> list[str]:
    """Imports that reach a private module or name of another package."""
    modules = _modules()
    found = []
    for importer, imported, name in _edges(modules):
        if _sees(_package(importer, modules), _package(imported, modules)):
            continue
        last = imported.rsplit(".", 1)[-1]
        if _private(last) or _private(name):
            found.append(f"{importer} -> {imported}{'.' + name if name else ''}")
    return sorted(set(found))


def test_the_graph_sees_function_local_and_relative_imports():
    graph = import_graph()
    assert "aeroid.errors" in graph["aeroid.models.model"]
    assert "aeroid.pipeline.storage.store" in graph["aeroid.pipeline.running.executors"]
    # a cycle built by hand is found, and so is a function-local import
    toy = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_cycles(toy) == [["a", "b", "c"]]
    tree = ast.parse("def f():\n    from . import x\nif TYPE_CHECKING:\n    import y\n")
    assert [type(n).__name__ for n in _runtime_imports(tree)] == ["ImportFrom"]


def test_no_import_cycles():
    cycles = import_cycles(import_graph())
    assert cycles == [], "import cycles: " + "; ".join(" / ".join(c) for c in cycles)


def test_no_private_name_crosses_a_package():
    crossings = private_crossings()
    assert crossings == [], "private names used across packages:\n" + "\n".join(crossings)


def test_the_public_namespace_holds_only_public_names():
    import aeroid

    tools = {"Any", "TYPE_CHECKING", "annotations", "importlib", "typing"}
    assert not tools & set(dir(aeroid))
    assert not [name for name in tools if hasattr(aeroid, name)]
    assert len(aeroid.__all__) == len(set(aeroid.__all__))
    assert dir(aeroid) == sorted(aeroid.__all__)
    # the errors come from the import, the rest from the lazy table: nothing listed twice
    assert set(aeroid.__all__) == {"__version__"} | set(aeroid._LAZY) | {
        n
        for n in aeroid.__all__
        if isinstance(getattr(aeroid, n), type)
        and issubclass(getattr(aeroid, n), aeroid.AeroidError | Warning)
    }
    assert "ResidualDriftWarning" in aeroid.__all__ and "identify" in aeroid.__all__


def _pair_information(ratio: float, scales: tuple[float, float, float]) -> np.ndarray:
    # unit-diagonal eigenvalues 1 +- rho, so the relative one is (1 - rho)/(1 + rho);
    # a third parameter without any effect; every row scaled as units would scale it
    rho = (1.0 - ratio) / (1.0 + ratio)
    c = np.array([[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 0.0]])
    d = np.diag(scales)
    return d @ c @ d


def test_one_identifiability_check_with_one_threshold():
    from aeroid.estimation import _filter_error, _output_error
    from aeroid.estimation import identifiability as _identifiability
    from aeroid.estimation.identifiability import RCOND, unidentifiable
    from aeroid.frequency import frequency_domain
    from aeroid.uncertainty import sensitivity as sens_module

    names = ["a", "b", "dead"]
    for scales in [(1.0, 1.0, 1.0), (1e6, 1e-3, 5.0)]:
        combos, null = unidentifiable(_pair_information(0.5 * RCOND, scales), names)
        assert combos == [("dead",), ("a", "b")] and null.tolist() == [True, True, True]
        combos, null = unidentifiable(_pair_information(4.0 * RCOND, scales), names)
        assert combos == [("dead",)] and null.tolist() == [False, False, True]
    # the same kernel, not a copy, behind every estimator and the design tools
    assert _output_error._combinations is unidentifiable
    for module in (_filter_error, frequency_domain, sens_module):
        assert module.unidentifiable is unidentifiable
    cov, combos, _ = sens_module._analyse_fisher(_pair_information(0.5 * RCOND, (1, 1, 1)), names)
    assert list(combos) == [("dead",), ("a", "b")] and np.all(np.isinf(np.diag(cov)))
    cov, combos, _ = sens_module._analyse_fisher(_pair_information(4.0 * RCOND, (2, 3, 1)), names)
    # the bound of the separable pair is the inverse of its 2 x 2 information
    c = _pair_information(4.0 * RCOND, (2, 3, 1))[:2, :2]
    assert np.allclose(cov[:2, :2], np.linalg.inv(c), rtol=1e-5)
    # no module keeps its own copy of the check
    copies = [
        p.name
        for p in ROOT.rglob("*.py")
        if p.name != "_identifiability.py"
        and ("def _unidentifiable(" in p.read_text() or "def _combinations(" in p.read_text())
    ]
    assert copies == []
    assert _identifiability.RCOND == 1e-9


def test_the_simulate_options_are_defined_once():
    from aeroid import adapters
    from aeroid.models.model import SIMULATE_OPTION_KEYS
    from aeroid.uncertainty import inference

    assert adapters.INTEGRATOR_OPTIONS is SIMULATE_OPTION_KEYS
    assert inference._SIM_OPTIONS is SIMULATE_OPTION_KEYS
    literal = '"method", "substeps", "rtol", "atol"'
    holders = sorted(p.name for p in ROOT.rglob("*.py") if literal in p.read_text())
    assert holders == ["model.py"]


MAX_MODULE_LINES = 800


def long_modules(limit: int = MAX_MODULE_LINES) -> dict[str, int]:
    """Every module in aeroid/ longer than ``limit`` lines, with its length."""
    counts = {
        name: len(path.read_text(encoding="utf-8").splitlines())
        for name, path in _modules().items()
    }
    return {name: n for name, n in counts.items() if n > limit}


def test_the_line_counter_sees_a_long_module():
    assert long_modules(limit=0)
    assert all(n > 0 for n in long_modules(limit=0).values())


def test_no_module_exceeds_800_lines():
    assert long_modules() == {}


class _Anonymise(ast.NodeTransformer):
    """Names and argument names become ``_`` so renamed copies still match."""

    def visit_Name(self, node: ast.Name) -> ast.AST:
        return ast.copy_location(ast.Name(id="_", ctx=node.ctx), node)

    def visit_arg(self, node: ast.arg) -> ast.AST:
        node.arg, node.annotation = "_", None
        return node


def repeated_functions(min_statements: int = 3) -> list[list[str]]:
    """Groups of functions whose bodies (docstring aside) are the same up to names."""
    import hashlib

    groups: dict[str, list[str]] = {}
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            body = node.body
            if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                body = body[1:]
            if len(body) < min_statements:
                continue  # one- and two-liners are signatures and forwards, not logic
            copy = ast.parse("\n".join(ast.unparse(s) for s in body))
            key = hashlib.sha1(ast.dump(_Anonymise().visit(copy)).encode()).hexdigest()
            groups.setdefault(key, []).append(f"{name}.{node.name}")
    return [sorted(g) for g in groups.values() if len(g) > 1]


# Repeats allowed for now, each with its reason (none today)
_PENDING: list[list[str]] = []


def test_the_duplicate_finder_sees_a_renamed_copy():
    a = ast.parse("def f(x):\n    y = x + 1\n    z = y * 2\n    return z\n")
    b = ast.parse("def g(u):\n    v = u + 1\n    w = v * 2\n    return w\n")
    dumps = [
        ast.dump(_Anonymise().visit(ast.Module(body=t.body[0].body, type_ignores=[])))
        for t in (a, b)
    ]
    assert dumps[0] == dumps[1]


def test_no_repeated_logic():
    assert [g for g in repeated_functions() if g not in _PENDING] == []


# -- repeated runs of statements (issue 50 part 5) -----------------------------------
# A block copied into a second function and edited there (other names, other words in
# its messages) is not a whole repeated function, so the check above misses it. This
# one compares runs of sibling statements inside functions by their shape: the node
# types in walk order, so names, attributes, keywords and literal values do not count.
# A run counts its nested statements; a place is reported once per run, and two runs
# that overlap (a table of like statements sliding over itself) are not a repeat.
# Docstrings and imports are left out; so is module and class level (constants,
# fields, signatures: boilerplate, not logic).
MIN_RUN_STATEMENTS = 6  # the six lines at which the `duplicates` command starts


def _shape(node: ast.AST) -> str:
    return " ".join(type(n).__name__ for n in ast.walk(node))


def _logic(block: list[ast.stmt]) -> list[ast.stmt]:
    return [
        s
        for s in block
        if not isinstance(s, ast.Import | ast.ImportFrom)
        and not (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))
    ]


def _function_blocks(tree: ast.AST) -> Iterator[tuple[str, list[ast.stmt]]]:
    """``(qualified function name, statement block)`` for every block inside a function."""

    def visit(node: ast.AST, scope: str, inside: bool) -> Iterator[tuple[str, list[ast.stmt]]]:
        for child in ast.iter_child_nodes(node):
            name, within = scope, inside
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = f"{scope}.{child.name}" if scope else child.name
                within = inside or not isinstance(child, ast.ClassDef)
            if within:
                for field in ("body", "orelse", "finalbody"):
                    block = getattr(child, field, None)
                    if isinstance(block, list) and block and isinstance(block[0], ast.stmt):
                        yield name, block
            yield from visit(child, name, within)

    yield from visit(tree, "", False)


def repeated_runs(
    min_statements: int = MIN_RUN_STATEMENTS, modules: dict[str, Path] | None = None
) -> list[tuple[str, ...]]:
    """Groups of functions sharing a run of `min_statements` or more statements of one shape."""
    # shape of the run -> (module, function, block number, first and last statement index)
    places: dict[tuple[str, ...], list[tuple[str, str, int, int, int]]] = {}
    for module, path in (modules or _modules()).items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for number, (function, block) in enumerate(_function_blocks(tree)):
            stmts = _logic(block)
            shapes = [_shape(s) for s in stmts]
            sizes = [sum(isinstance(n, ast.stmt) for n in ast.walk(s)) for s in stmts]
            for i in range(len(stmts)):
                j, total = i, 0
                while j < len(stmts) and total < min_statements:
                    total, j = total + sizes[j], j + 1
                if total < min_statements:
                    break
                places.setdefault(tuple(shapes[i:j]), []).append((module, function, number, i, j))
    groups: set[tuple[str, ...]] = set()
    for found in places.values():
        # runs of one block that overlap or touch are one stretch (a table of like lines)
        spans: list[tuple[str, str, int, int, int]] = []
        for m, f, n, a, b in sorted(found):
            if spans and spans[-1][:3] == (m, f, n) and a <= spans[-1][4]:
                spans[-1] = (m, f, n, spans[-1][3], max(b, spans[-1][4]))
            else:
                spans.append((m, f, n, a, b))
        if len(spans) > 1:
            groups.add(tuple(sorted(f"{m}.{f}" for m, f, *_ in spans)))
    return sorted(groups)


# Repeats allowed, each with its reason (look-alikes only: a repeat of one job is merged)
_ALLOWED_RUNS: dict[tuple[str, ...], str] = {
    ("aeroid.adapters.jsbsim._number", "aeroid.models._aircraft_parts._finite"): (
        "alike only: a float check per package, each with its own error class and wording"
    ),
}


def test_the_run_finder_sees_an_edited_copy_and_not_a_table(tmp_path: Path):
    body = """
    if not isinstance(value, dict):
        raise TypeError(f"{name}: expected a dict, got {value!r}")
    unknown = sorted(set(value) - set(keys))
    if unknown:
        raise KeyError(f"{name}: unknown keys {unknown}")
    total = 0.0
    for k, v in value.items():
        total += float(v)
    return total
"""
    copy = body.replace("value", "spec").replace("expected a dict", "expected a mapping")
    planted = tmp_path / "planted.py"
    planted.write_text(f"def f(value, name, keys):{body}\ndef g(spec, name, keys):{copy}")
    assert repeated_runs(modules={"planted": planted}) == [("planted.f", "planted.g")]
    # a shared run one statement short of the threshold (the loop gone) is not a repeat
    shorter = copy.split("    total = 0.0")[0] + "    return len(spec)\n"
    planted.write_text(f"def f(value, name, keys):{body}\ndef g(spec, name, keys):{shorter}")
    assert repeated_runs(modules={"planted": planted}) == []
    table = "".join(f"    x{i} = d.get('k{i}', {i})\n" for i in range(20))
    planted.write_text(f"def h(d):\n{table}")
    assert repeated_runs(modules={"planted": planted}) == []


def test_no_repeated_runs_of_statements():
    found = repeated_runs()
    assert [g for g in found if g not in _ALLOWED_RUNS] == []
    assert [g for g in _ALLOWED_RUNS if g not in found] == []  # an allowance outliving its repeat


# -- the floors (issue 50): imports flow one way between the rooms ------------------
# Top floor first. A module imports from its own room or from a lower floor, never
# up and never sideways into another room of its floor; function-local imports count.
FLOORS: list[set[str]] = [
    # the package's face: ``python -m aeroid`` is the command line
    {"aeroid", "aeroid.__main__", "aeroid.cli", "aeroid.support"}
    | {"aeroid.pipeline", "aeroid.adapters"},
    {"aeroid.uncertainty", "aeroid.frequency"},
    {"aeroid.estimation"},
    {"aeroid.models"},
    {"aeroid.io"},
    {"aeroid.reports"},
    {"leaves"},  # errors, _checks, _records, ...: the modules left in aeroid/
]
_TOP = FLOORS[0]


def _room(module: str, modules: dict[str, Path]) -> str:
    parts = module.split(".")
    if module == "aeroid" or module in _TOP:
        return module
    room = ".".join(parts[:2])
    return room if (ROOT / parts[1] / "__init__.py").exists() else "leaves"


def upward_imports(graph: dict[str, set[str]], room: dict[str, str]) -> list[str]:
    """Imports that go up a floor, or sideways from one room to another below the top."""
    floor = {r: i for i, rooms in enumerate(FLOORS) for r in rooms}
    found = []
    for importer, targets in graph.items():
        a = room[importer]
        for imported in targets:
            b = room[imported]
            if a == b or (floor[a] == 0 and floor[b] == 0):
                continue
            if floor[b] <= floor[a]:
                found.append(f"{importer} ({a}) -> {imported} ({b})")
    return sorted(found)


def test_every_module_has_a_room_on_a_floor():
    modules = _modules()
    rooms = {_room(m, modules) for m in modules}
    assert rooms <= set().union(*FLOORS), rooms - set().union(*FLOORS)
    # no flat module left beside the rooms but the package's face and the leaves
    loose = sorted(p.stem for p in ROOT.glob("*.py") if not p.stem.startswith("_"))
    assert loose == ["cli", "errors", "support"]


def test_the_floor_check_sees_an_upward_import():
    room = {"a.m": "aeroid.models", "a.e": "aeroid.estimation", "a.l": "leaves"}
    assert upward_imports({"a.e": {"a.m"}, "a.m": {"a.l"}, "a.l": set()}, room) == []
    assert upward_imports({"a.m": {"a.e"}, "a.e": set(), "a.l": set()}, room) == [
        "a.m (aeroid.models) -> a.e (aeroid.estimation)"
    ]
    sideways = {"a.f": "aeroid.frequency", "a.u": "aeroid.uncertainty"}
    assert upward_imports({"a.f": {"a.u"}, "a.u": set()}, sideways)


def test_imports_flow_one_way_between_the_rooms():
    modules = _modules()
    room = {m: _room(m, modules) for m in modules}
    assert upward_imports(import_graph(), room) == []


def test_old_module_paths_still_import():
    # run apart: the old names must work from a fresh interpreter, lazily
    import subprocess
    import sys

    code = (
        "import pickle, sys, aeroid\n"
        "assert not [m for m in ('scipy.optimize', 'aeroid.estimation') if m in sys.modules]\n"
        "import aeroid.identification as old\n"  # flat layout
        "from aeroid.estimation import identification as new\n"
        "assert old is new and old.__name__ == 'aeroid.estimation.identification'\n"
        "assert old.__spec__.name == 'aeroid.estimation.identification'\n"
        "from aeroid.aircraft import AircraftConstants\n"  # flat layout
        "from aeroid.models.aircraft import AircraftConstants as A2\n"
        "assert AircraftConstants is A2\n"
        "import aeroid.frequency\n"
        "old_fr = aeroid.frequency.frequency_response\n"  # flat layout
        "from aeroid.frequency.response import frequency_response\n"
        "assert old_fr is frequency_response\n"
        "from aeroid.frequency import frequency_response as f2\n"
        "assert f2 is frequency_response\n"
        "assert aeroid.plotting is sys.modules['aeroid.reports.plotting']\n"  # flat layout
        "from aeroid import _output_error\n"
        "assert _output_error.__name__ == 'aeroid.estimation._output_error'\n"
        "assert pickle.loads(b'caeroid.identification\\nidentify\\n.') is aeroid.identify\n"  # flat layout
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_stored_names_stay_those_of_the_flat_layout():
    from aeroid._aliases import MOVED, legacy_name
    from aeroid.models.model import SimulationResult
    from aeroid.pipeline.storage import codec

    flat = "aeroid.identification"  # flat layout
    assert legacy_name("aeroid.estimation.identification") == flat
    assert legacy_name("aeroid.pipeline.keys") == "aeroid.pipeline.keys"
    # the engine's modules moved into its seams keep their names in stored records too
    engine = ("aeroid.pipeline.store", "aeroid.pipeline.builtin_stages")  # flat layout
    assert legacy_name("aeroid.pipeline.storage.store") == engine[0]
    assert legacy_name("aeroid.pipeline.stages.builtin") == engine[1]
    assert legacy_name("mine.vehicle") == "mine.vehicle"
    # every old name leads to a module that exists, and each module has one old name
    assert len(set(MOVED.values())) == len(MOVED)
    for new in MOVED.values():
        assert (ROOT.parent / (new.replace(".", "/") + ".py")).is_file(), new
    # the codec writes a class's module by its flat-layout name, and reads it back
    written = codec._qualified(SimulationResult)
    assert written == "aeroid._simulation_results:SimulationResult"  # flat layout
    assert codec._resolve_own(written) is SimulationResult
    assert codec._resolve_own("aeroid.model:SimulationResult") is SimulationResult  # flat layout
