"""The import graph of `taichi_ndf` and `inverse`: no cycle, no import up the layer order
(docs/architecture.md, "Layers"), and no module over 400 lines.

The graph is read from the source with `ast` (nothing is imported), with every import
statement anywhere in a module: at the top, inside a function, under `TYPE_CHECKING`. An
edge A -> B means that importing A (or running the function of A that holds the import)
imports B: `from P import name` is an edge to the module P.name where that is a module, else
to P; importing a module also runs the `__init__` of every package above it, an edge to each
of them (except A's own packages, already being imported).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("taichi_ndf", "inverse")
DOC = ROOT / "docs" / "architecture.md"
MAX_LINES = 400

# The layer order, lowest first (docs/architecture.md, "Layers"). A module belongs to the
# layer of the longest prefix listed that names it or a package above it (the top packages
# `taichi_ndf` and `inverse` name only their own __init__); it may import modules of its own
# layer and of the layers below, never of a layer above.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    # Plumbing without physics: the Taichi runtime, jets, checks, files, drawing, progress.
    ("runtime", ("taichi_ndf", "taichi_ndf.runtime", "taichi_ndf.jets", "taichi_ndf.checks",
                 "taichi_ndf.extras", "taichi_ndf.progress", "taichi_ndf.io",
                 "taichi_ndf.render")),
    # The problem and its plain specifications: surface, field, shell, boundary conditions,
    # loads, samples, operator, model, objective terms (contact's barrier included), the
    # dimensional scales, the training (with Adam's) and grid specifications, the memory
    # they imply.
    ("model", ("taichi_ndf.geometry", "taichi_ndf.field", "taichi_ndf.shell",
               "taichi_ndf.boundary", "taichi_ndf.problem", "taichi_ndf.objective",
               "taichi_ndf.contact")),
    # Minimisers of Π at one load factor on one discretisation, contact's Newton hook, and
    # what a minimisation changes and saves: state, checkpoint, backoff, callbacks.
    ("minimise", ("taichi_ndf.minimise", "taichi_ndf.contact.newton_contact")),
    # Solve drivers: continuation over load steps and grid levels, the estimates that solve,
    # and the discretisations (one per field type) that the tools solve through.
    ("solve", ("taichi_ndf.solve", "taichi_ndf.discretise")),
    # Scene reading: TOML into a plain specification (model, field, training, output).
    ("scene", ("taichi_ndf.scene",)),
    # The applications: a scene run with its outputs, the tools, benchmarks, studies, viewers.
    ("app", ("taichi_ndf.app", "taichi_ndf.cli", "taichi_ndf.validation", "taichi_ndf.sweep",
             "taichi_ndf.export", "taichi_ndf.viewer")),
    # Inverse problems on top of the forward toolkit, and their tools.
    ("inverse", ("inverse", "inverse.material", "inverse.sft")),
    ("inverse app", ("inverse.cli",)),
)

# Imports that go up the layer order today, each with why it is left: the list may only
# shrink (an entry that no longer occurs fails `test_known_upward_imports_still_occur`).
KNOWN_UPWARD: dict[tuple[str, str], str] = {}


def _modules() -> dict[str, tuple[Path, bool]]:
    """Module name -> (file, is a package's __init__)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            init = parts[-1] == "__init__"
            found[".".join(parts[:-1] if init else parts)] = (path, init)
    return found


MODULES = _modules()


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def _dynamic(node: ast.AST, tree: ast.Module) -> list[str]:
    """The modules an `importlib.import_module(...)` call names: a string, or an f-string
    "prefix.{...}" whose placeholder is looked up in a module-level dict of names (the lazy
    `__getattr__` of `taichi_ndf.shell` and `taichi_ndf.validation`): the prefix joined to each
    string value of those dicts that makes a module, else every module under the prefix."""
    if not (isinstance(node, ast.Call) and node.args
            and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"):
        return []
    name = node.args[0]
    if isinstance(name, ast.Constant) and isinstance(name.value, str):
        return [name.value]
    if not (isinstance(name, ast.JoinedStr) and isinstance(name.values[0], ast.Constant)):
        return []
    prefix = name.values[0].value
    values = {v.value for d in ast.walk(tree) if isinstance(d, ast.Dict)
              for v in d.values if isinstance(v, ast.Constant) and isinstance(v.value, str)}
    named = [prefix + v for v in sorted(values) if prefix + v in MODULES]
    return named or [m for m in MODULES if m.startswith(prefix)]


def _imports(name: str, path: Path, init: bool) -> dict[str, int]:
    """The project modules `name` imports -> the first line that does."""
    package = name if init else name.rpartition(".")[0]
    targets: dict[str, int] = {}
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        named = _dynamic(node, tree)
        if isinstance(node, ast.Import):
            named = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = node.module or ""
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            named = [f"{source}.{a.name}" if f"{source}.{a.name}" in MODULES else source
                     for a in node.names]
        for target in named:
            while target and target not in MODULES:  # `import a.b.c` of a non-module c
                target = target.rpartition(".")[0]
            if not target:
                continue
            own = _ancestors(name)
            for module in (*_ancestors(target), target):
                if module != name and module not in own:
                    targets.setdefault(module, node.lineno)
    return targets


GRAPH = {name: _imports(name, path, init) for name, (path, init) in MODULES.items()}


def layer_of(module: str) -> int:
    best, layer = -1, None
    for index, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            inside = module.startswith(prefix + ".") and prefix not in PACKAGES
            if (module == prefix or inside) and len(prefix) > best:
                best, layer = len(prefix), index
    if layer is None:
        raise KeyError(module)
    return layer


def _cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _upward() -> dict[tuple[str, str], str]:
    return {(a, b): f"{MODULES[a][0].relative_to(ROOT)}:{line} ({LAYERS[layer_of(a)][0]}) "
                    f"imports {b} ({LAYERS[layer_of(b)][0]})"
            for a, targets in GRAPH.items() for b, line in targets.items()
            if layer_of(b) > layer_of(a)}


def test_the_graph_is_read(tmp_path):
    """The parser sees the imports it must: top-level, function-local, relative."""
    assert "taichi_ndf.problem.model" in GRAPH["taichi_ndf.scene.reader"]
    assert "taichi_ndf.runtime" in GRAPH["taichi_ndf"]  # inside __getattr__
    assert "taichi_ndf.boundary" in GRAPH["taichi_ndf.problem.model"]
    assert "taichi_ndf.boundary.conditions" in GRAPH["taichi_ndf.boundary"]
    # importlib.import_module in a lazy __getattr__: the modules its dict names, no others
    assert "taichi_ndf.shell.materials" in GRAPH["taichi_ndf.shell"]
    assert "taichi_ndf.shell.hessian" not in GRAPH["taichi_ndf.shell"]
    assert "taichi_ndf.validation.runner" in GRAPH["taichi_ndf.validation"]
    # a package's __init__ runs first: an edge to it, but not from its own modules
    assert "taichi_ndf.contact" in GRAPH["taichi_ndf.app.outputs"]
    assert "taichi_ndf.contact" not in GRAPH["taichi_ndf.contact.config"]
    # relative imports, as written in a module and in a package's __init__
    source = tmp_path / "module.py"
    source.write_text("from .conditions import BoundaryConditions\nfrom . import frame\n"
                      "from .. import jets\n")
    assert set(_imports("taichi_ndf.boundary.fold", source, False)) == {
        "taichi_ndf.boundary.conditions", "taichi_ndf.boundary.frame", "taichi_ndf.jets"}
    init = tmp_path / "__init__.py"
    init.write_text("from .fold import Fold\n")
    assert set(_imports("taichi_ndf.boundary", init, True)) == {"taichi_ndf.boundary.fold"}
    assert _cycles({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"a": 1}}) == [
        ["a", "b", "c"]]


def test_every_module_has_a_layer():
    missing = []
    for module in MODULES:
        try:
            layer_of(module)
        except KeyError:
            missing.append(module)
    assert not missing, f"modules in no layer of LAYERS: {missing}"


def test_no_import_cycle():
    cycles = _cycles(GRAPH)
    described = ["; ".join(f"{a} -> {b} (line {GRAPH[a][b]})" for a in cycle
                           for b in cycle if b in GRAPH[a]) for cycle in cycles]
    assert not cycles, "import cycles:\n" + "\n".join(described)


def test_no_upward_import():
    unexpected = {edge: text for edge, text in _upward().items() if edge not in KNOWN_UPWARD}
    assert not unexpected, "imports up the layer order:\n" + "\n".join(unexpected.values())


def test_known_upward_imports_still_occur():
    gone = sorted(set(KNOWN_UPWARD) - set(_upward()))
    assert not gone, f"no longer upward (remove from KNOWN_UPWARD): {gone}"


def test_scene_reading_does_not_solve():
    """The scene layer reads TOML into a plain specification: it imports nothing of the
    minimise and solve layers (the estimates that solve run when a run starts)."""
    scene = [index for index, (name, _) in enumerate(LAYERS) if name == "scene"][0]
    solving = {index for index, (name, _) in enumerate(LAYERS) if name in ("minimise", "solve")}
    found = [f"{a} imports {b}" for a, targets in GRAPH.items() if layer_of(a) == scene
             for b in targets if layer_of(b) in solving]
    assert not found, found


@pytest.mark.parametrize("package", PACKAGES)
def test_no_module_over_400_lines(package):
    long = {str(path.relative_to(ROOT)): n for name, (path, _) in MODULES.items()
            if name.split(".")[0] == package
            and (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines (split along concepts): {long}"


def _doc_table(heading: str) -> list[list[str]]:
    """The rows (cells) of the first table under `## heading` in docs/architecture.md."""
    section = DOC.read_text().split(f"\n## {heading}\n", 1)[1].split("\n## ", 1)[0]
    rows = [line.strip().strip("|").split(" | ") for line in section.splitlines()
            if line.startswith("| ")]
    return [[cell.strip() for cell in row] for row in rows[1:]]  # without the header


def test_the_documented_layers_are_layers():
    """docs/architecture.md's "Layers" table names the layers of LAYERS, in order, each with
    the same modules (written without `taichi_ndf.`)."""
    documented = [(row[0], sorted(n if n.startswith("inverse") else f"taichi_ndf.{n}"
                                  for n in re.findall(r"`([^`]+)`", row[1])))
                  for row in _doc_table("Layers")]
    expected = [(name, sorted(p for p in prefixes if p != "taichi_ndf"))
                for name, prefixes in LAYERS]
    assert documented == expected


def test_the_module_table_lists_every_module_with_its_layer():
    rows = {re.fullmatch(r"`(.+)`", row[0]).group(1): row[1] for row in _doc_table("Modules")}
    listed = {str(path.relative_to(ROOT)): LAYERS[layer_of(name)][0]
              for name, (path, _) in MODULES.items()}
    assert sorted(set(listed) - set(rows)) == [], "modules without a row"
    assert sorted(set(rows) - set(listed)) == [], "rows of no module"
    wrong = {m: (rows[m], layer) for m, layer in listed.items() if rows[m] != layer}
    assert not wrong, f"documented layer != LAYERS': {wrong}"


def _defined_names() -> set[str]:
    """Every name the code defines (functions, classes, assigned names and attributes,
    arguments, dataclass fields), every module's name, and the words of its strings."""
    names = set()
    for name, (path, _) in MODULES.items():
        names.update(name.split("."))
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.arg):
                names.add(node.arg)
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                names.update(re.findall(r"\w+", node.value))
    return names


def test_the_main_api_names_exist():
    """Every code name in docs/architecture.md's "Main APIs" table (`name`, `a.b(...)`,
    `.method`) is defined in the code: a removed or renamed function fails here."""
    defined, missing = _defined_names(), []
    for row in _doc_table("Main APIs"):
        for token in re.findall(r"`([^`]+)`", " | ".join(row)):
            head = token.split("(")[0]
            name = re.match(r"\.?([A-Za-z_][\w.]*)", token)
            if (name is None or " " in head or "-" in head or token.endswith((".py", "/"))
                    or token.startswith("ti.")):  # commands, files, the Taichi language
                continue
            if name.group(1).rstrip(".").split(".")[-1] not in defined:
                missing.append(token)
    assert not missing, f"names in the Main APIs table that the code does not define: {missing}"
