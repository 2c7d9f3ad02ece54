"""The code's layout, read from its own source: imports run one way (no circle between files or
between packages, counting imports inside functions), no package holds more than a fifth of
the lines, imports live at the top of files, functions stay short, module names do not
collide, and papers are named rather than numbered."""

from __future__ import annotations

import ast
import re
from collections import Counter, defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "motiongen"
MAX_PACKAGE_SHARE = 0.20
MAX_FUNCTION_LINES = 80
# A longer function says why on its `def` line or the line above: `# long: <reason>`.
LONG_MARK = re.compile(r"#\s*long:", re.I)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}
TREES = {m: ast.parse(p.read_text(), filename=str(p)) for m, p in MODULES.items()}


def _package_of(module: str) -> str:
    """motiongen.scene.occupancy -> motiongen.scene; a top-level module is its own package."""
    parts = module.split(".")
    if len(parts) > 2 or MODULES[module].name == "__init__.py":
        return ".".join(parts[:2])
    return module


def _resolve(name: str) -> str | None:
    """The motiongen module a dotted import name lands in (`a.b.Name` -> `a.b`)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported_names(module: str, node) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:
        pkg = module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]
        up = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
        base = ".".join(up + ([base] if base else []))
    return [f"{base}.{a.name}" for a in node.names]


def _import_nodes(tree):
    return [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]


def _file_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = defaultdict(set)
    for module, tree in TREES.items():
        for node in _import_nodes(tree):
            for name in _imported_names(module, node):
                target = _resolve(name) if name.startswith("motiongen") else None
                if target and target != module:
                    graph[module].add(target)
    return graph


def _cycles(nodes, graph) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan, iterative)."""
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], [0]
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter[0]; counter[0] += 1
        stack.append(root); on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter[0]; counter[0] += 1
                    stack.append(w); on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop(); on_stack.discard(w); component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_cycle_finder_finds_a_planted_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(["a", "b", "c", "d"], graph) == [["a", "b", "c"]]
    assert _cycles(["a", "b"], {"a": {"b"}}) == []


def test_no_import_circle_between_files():
    graph = _file_graph()
    assert _cycles(sorted(MODULES), graph) == []


def test_no_import_circle_between_packages():
    packages: dict[str, set[str]] = defaultdict(set)
    for a, targets in _file_graph().items():
        for b in targets:
            if _package_of(a) != _package_of(b):
                packages[_package_of(a)].add(_package_of(b))
    assert _cycles(sorted({_package_of(m) for m in MODULES}), packages) == []


def test_no_package_holds_more_than_a_fifth_of_the_lines():
    lines = Counter()
    for module, path in MODULES.items():
        lines[_package_of(module)] += len(path.read_text().splitlines())
    total = sum(lines.values())
    big = {p: f"{n / total:.0%}" for p, n in lines.items() if n > MAX_PACKAGE_SHARE * total}
    assert big == {}


def _inner_imports():
    """(module, line, text, comment-above) of every import inside a function or class."""
    for module, tree in TREES.items():
        top = {id(n) for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))}
        # imports under a module-level `if`/`try` (TYPE_CHECKING, optional backends) are top-level too
        for stmt in tree.body:
            if isinstance(stmt, (ast.If, ast.Try)):
                top |= {id(n) for n in _import_nodes(stmt)}
        lines = MODULES[module].read_text().splitlines()
        for node in _import_nodes(tree):
            if id(node) not in top:
                yield module, node, lines[node.lineno - 1], lines[node.lineno - 2].strip()


def test_no_function_level_import_of_motiongen():
    inner = [f"{m}:{n.lineno}" for m, n, _, _ in _inner_imports()
             if any(name.startswith("motiongen") for name in _imported_names(m, n))]
    assert inner == []


def test_function_level_imports_say_why():
    """A third-party import kept inside a function (a heavy or optional dependency) carries a
    comment on its line or the line above."""
    silent = [f"{m}:{n.lineno}" for m, n, text, above in _inner_imports()
              if "#" not in text and not above.startswith("#")]
    assert silent == []


def test_long_functions_say_why():
    long_ = []
    for module, tree in TREES.items():
        lines = MODULES[module].read_text().splitlines()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                length = node.end_lineno - node.lineno + 1
                context = " ".join(lines[max(first - 2, 0): node.lineno])
                if length > MAX_FUNCTION_LINES and not LONG_MARK.search(context):
                    long_.append(f"{module}.{node.name} ({length} lines)")
    assert long_ == []


def test_module_names_do_not_collide():
    names = Counter(p.name for p in MODULES.values() if p.name not in ("__init__.py", "__main__.py"))
    assert {n: c for n, c in names.items() if c > 1} == {}


@pytest.mark.parametrize("folder", ["motiongen", "docs", "benchmarks", "tests", "scripts"])
def test_papers_are_named_not_numbered(folder):
    """A reader cannot resolve 'seed 001'; the code and docs name the paper (the TRUMANS
    supplement, LEMO, the multi-view capture paper)."""
    numbered = re.compile(r"\bseeds?\s+00\d\b|seeds/00\d", re.I)
    paths = [REPO / "README.md"] if folder == "docs" else []
    paths += [p for p in (REPO / folder).rglob("*") if p.suffix in (".py", ".md", ".yaml", ".sh")]
    hits = [f"{p.relative_to(REPO)}:{i + 1}" for p in paths if p.name != "test_structure.py"
            for i, line in enumerate(p.read_text().splitlines()) if numbered.search(line)]
    assert hits == []
