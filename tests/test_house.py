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


def _private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def private_crossings() -> list[str]:
    """Imports that reach a private module or name of another package."""
    modules = _modules()
    found = []
    for importer, imported, name in _edges(modules):
        if _package(importer, modules) == _package(imported, modules):
            continue
        last = imported.rsplit(".", 1)[-1]
        if _private(last) or _private(name):
            found.append(f"{importer} -> {imported}{'.' + name if name else ''}")
    return sorted(set(found))


def test_the_graph_sees_function_local_and_relative_imports():
    graph = import_graph()
    assert "aeroid.errors" in graph["aeroid.model"]
    assert "aeroid.pipeline.store" in graph["aeroid.pipeline.runner"]
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
    from aeroid import _filter_error, _identifiability, _output_error, frequency_domain
    from aeroid import sensitivity as sens_module
    from aeroid._identifiability import RCOND, unidentifiable

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
    from aeroid import adapters, inference
    from aeroid.model import SIMULATE_OPTION_KEYS

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
