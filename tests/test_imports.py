"""Dependencies point downstream: no import cycle among the modules of ``usdbtf``, none
between its subpackages (``docs/architecture.md`` has the layering).

Every ``import`` and ``from ... import`` inside ``pipeline/usdbtf`` is counted, at module
level and inside functions alike (a function-level import is a dependency too, only a late
one).  Importing ``a.b.c`` from outside ``a.b`` also runs ``a.b/__init__``, so that package
is a dependency as well.  The checker itself is checked: a deliberately cyclic pair of
modules must fail it.
"""
from __future__ import annotations

import ast
import textwrap
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "pipeline" / "usdbtf"


def module_files(package: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package ``__init__``) for every .py under ``package``."""
    out = {}
    for f in sorted(package.rglob("*.py")):
        parts = list(f.relative_to(package.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    return out


def _known(name: str, modules) -> str | None:
    """The longest prefix of ``name`` that is a module of the package (None: outside it)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(package: Path) -> dict[str, set[str]]:
    """Module -> modules of ``package`` it imports (module- and function-level)."""
    modules = module_files(package)
    root = package.name
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, (path, is_pkg) in modules.items():
        here = name.split(".") if is_pkg else name.split(".")[:-1]
        targets = []
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets += [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = (node.module or "") if node.level == 0 else \
                    ".".join(here[:len(here) - node.level + 1] + ([node.module] if node.module else []))
                # ``from pkg import name``: name is a submodule, or an attribute of pkg.
                targets += [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        for target in targets:
            if target != root and not target.startswith(root + "."):
                continue
            found = _known(target, modules)
            if found is None:
                continue
            graph[name].add(found)
            # Importing a.b.c runs the __init__ of every package on the way that is not
            # already one of this module's own parents.
            parts = found.split(".")
            for i in range(2, len(parts)):
                parent = ".".join(parts[:i])
                if not name.startswith(parent + ".") and parent in modules:
                    graph[name].add(parent)
        graph[name].discard(name)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle [a, b, ..., a] of the directed graph, or None (iterative depth-first search)."""
    state = {node: 0 for node in graph}           # 0 new, 1 on the stack, 2 done
    for start in sorted(graph):
        if state[start]:
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path = [start]
        state[start] = 1
        while stack:
            node, children = stack[-1]
            for child in children:
                if state.get(child, 2) == 1:
                    return path[path.index(child):] + [child]
                if state.get(child, 2) == 0:
                    state[child] = 1
                    stack.append((child, iter(sorted(graph[child]))))
                    path.append(child)
                    break
            else:
                state[node] = 2
                stack.pop()
                path.pop()
    return None


def subpackage_graph(graph: dict[str, set[str]], root: str) -> dict[str, set[str]]:
    """The same dependencies between the package's direct children (subpackages and top-level
    modules).  The root ``__init__`` is the facade (``__version__``, plugin registration at
    import) and not a child: its own imports are checked in the module graph."""
    def child(module: str) -> str | None:
        parts = module.split(".")
        return ".".join(parts[:2]) if len(parts) > 1 else None

    out: dict[str, set[str]] = {}
    for a, targets in graph.items():
        ca = child(a)
        if ca is None:
            continue
        out.setdefault(ca, set())
        for b in targets:
            cb = child(b)
            if cb is not None and cb != ca:
                out[ca].add(cb)
                out.setdefault(cb, set())
    return out


def assert_acyclic(graph: dict[str, set[str]], what: str = "import cycle") -> None:
    cycle = find_cycle(graph)
    assert cycle is None, f"{what}: " + " -> ".join(cycle)


def test_no_import_cycle_between_modules():
    graph = import_graph(PACKAGE)
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300      # the scan found the imports
    assert_acyclic(graph)


def test_no_import_cycle_between_subpackages():
    packages = subpackage_graph(import_graph(PACKAGE), PACKAGE.name)
    assert {"usdbtf.usd", "usdbtf.render", "usdbtf.unwrap", "usdbtf.mesh", "usdbtf.io"} <= set(packages)
    assert_acyclic(packages, "import cycle between subpackages")


#: The layers inside ``usd/`` (docs/architecture.md): each imports only from its own layer or a
#: lower one.  ``usd`` itself is the schema core (plugin, genschema, material, read, density).
USD_LAYERS = ["usdbtf.usd", "usdbtf.usd.asset", "usdbtf.usd.scenes", "usdbtf.usd.preview"]


def usd_layer(module: str) -> int | None:
    """Index in :data:`USD_LAYERS` of a module under ``usdbtf.usd`` (None: outside it)."""
    for i in reversed(range(len(USD_LAYERS))):
        if module == USD_LAYERS[i] or module.startswith(USD_LAYERS[i] + "."):
            return i
    return None


def upward_usd_imports(graph: dict[str, set[str]]) -> list[str]:
    """``a -> b`` for every import inside ``usd/`` from a lower layer to a higher one."""
    out = []
    for a, targets in sorted(graph.items()):
        la = usd_layer(a)
        out += [f"{a} -> {b}" for b in sorted(targets)
                if la is not None and usd_layer(b) is not None and usd_layer(b) > la]
    return out


def test_usd_is_split_by_concern_and_imports_only_downward():
    graph = import_graph(PACKAGE)
    layers = {usd_layer(m) for m in graph} - {None}
    assert layers == {0, 1, 2, 3}                                     # every layer has modules
    assert {"usdbtf.usd.asset.package", "usdbtf.usd.scenes.build", "usdbtf.usd.preview.hydra",
            "usdbtf.usd.material"} <= set(graph)
    # the scan sees imports across the layers (build packages assets, hydra writes scenes)
    assert "usdbtf.usd.asset.package" in graph["usdbtf.usd.scenes.build"]
    assert "usdbtf.usd.scenes.scene" in graph["usdbtf.usd.preview.hydra"]
    assert upward_usd_imports(graph) == []          # so no cycle between the layers either


def test_the_usd_layer_check_finds_an_upward_import():
    graph = {"usdbtf.usd.asset.package": {"usdbtf.usd.scenes.plan", "usdbtf.usd.material"},
             "usdbtf.usd.material": set(), "usdbtf.usd.scenes.plan": set()}
    assert upward_usd_imports(graph) == ["usdbtf.usd.asset.package -> usdbtf.usd.scenes.plan"]


def _package(root: Path, files: dict[str, str]) -> Path:
    """A throw-away package ``demo`` under ``root`` made of ``files`` (path -> source)."""
    for rel, text in files.items():
        path = root / "demo" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root / "demo"


def test_the_checker_finds_a_function_level_cycle(tmp_path):
    graph = import_graph(_package(tmp_path, {"__init__.py": "", "high.py": "from .low import f\n",
                                             "low.py": "def f():\n    from .high import g\n    return g\n"}))
    assert graph["demo.high"] == {"demo.low"} and graph["demo.low"] == {"demo.high"}
    with pytest.raises(AssertionError, match=r"import cycle: demo\.high -> demo\.low -> demo\.high"):
        assert_acyclic(graph)


def test_the_checker_finds_a_cycle_between_subpackages(tmp_path):
    """No module cycle, but p uses q and q uses p (through other modules); ``import demo.p.two``
    also runs demo/p/__init__."""
    graph = import_graph(_package(tmp_path, {"__init__.py": "", "p/__init__.py": "", "p/two.py": "",
                                             "p/one.py": "from ..q import x\n", "q/__init__.py": "",
                                             "q/x.py": "import demo.p.two\n"}))
    assert_acyclic(graph)
    assert graph["demo.q.x"] == {"demo.p.two", "demo.p"}
    with pytest.raises(AssertionError, match=r"between subpackages: demo\.p -> demo\.q -> demo\.p"):
        assert_acyclic(subpackage_graph(graph, "demo"), "import cycle between subpackages")


def test_the_checker_passes_a_layering(tmp_path):
    graph = import_graph(_package(tmp_path, {"__init__.py": "from .top import run\n", "base.py": "",
                                             "top.py": "from . import base\ndef run():\n    from .base import x\n"}))
    assert graph["demo.top"] == {"demo.base"} and graph["demo"] == {"demo.top"}
    assert_acyclic(graph)
    assert_acyclic(subpackage_graph(graph, "demo"))
