"""The house's shape (issue 11): no import circle among highway_srl's modules, dependencies point down the
layers, no private name (_x) is imported from another module, no function is over 60 lines and no source file
over 450."""

import ast
import re
from pathlib import Path

import highway_srl

PACKAGE = Path(highway_srl.__file__).parent
# lower number = lower layer; a module may import only from its own layer or below. The root package
# (highway_srl/__init__.py) is the public facade: it may import any layer lazily, and others take only
# __version__ from it.
LAYERS = {"constants": 0, "scenarios": 0, "interrupts": 0, "sim": 1, "rules": 2, "backends": 2, "env": 3, "agents": 3,
          "sb3": 4, "experiments": 4, "study": 5, "commands": 6, "cli": 7}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = ["highway_srl", *path.relative_to(PACKAGE).with_suffix("").parts]
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(path: Path) -> list[tuple[str, list[str]]]:
    """(module, names) of every highway_srl import in the file, at any depth (lazy imports count)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("highway_srl"):
            found.append((node.module, [a.name for a in node.names]))
        elif isinstance(node, ast.Import):
            found += [(a.name, []) for a in node.names if a.name.startswith("highway_srl")]
    return found


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    graph = {}
    for name, path in mods.items():
        deps = set()
        for module, names in _imports(path):
            # `from highway_srl.experiments import train` imports the module highway_srl.experiments.train
            deps |= {f"{module}.{n}" for n in names if f"{module}.{n}" in mods} or {module}
        graph[name] = {d for d in deps if d in mods and d != name}
    return graph


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS[parts[1]] if len(parts) > 1 else None


def test_every_subpackage_and_top_level_module_has_a_layer():
    assert {m.split(".")[1] for m in _modules() if "." in m} == set(LAYERS)


def test_no_import_circle_among_the_modules():
    graph, state, circles = _graph(), {}, []

    def visit(node, path):
        state[node] = "open"
        for dep in sorted(graph[node]):
            if state.get(dep) == "open":
                circles.append(path[path.index(dep):] + [dep])
            elif dep not in state:
                visit(dep, path + [dep])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert circles == []


def test_dependencies_point_down_the_layers():
    upward = []
    for module, deps in _graph().items():
        if _layer(module) is None:
            continue  # the facade
        for dep in deps:
            if dep != "highway_srl" and _layer(dep) > _layer(module):
                upward.append(f"{module} -> {dep}")
    assert upward == []


def test_only_the_version_is_taken_from_the_facade():
    mods = _modules()
    taken = {n for path in mods.values() for module, names in _imports(path) if module == "highway_srl"
             for n in names if f"highway_srl.{n}" not in mods}  # `from highway_srl import commands` is a module
    assert taken <= {"__version__"}


def test_no_private_name_is_imported_from_another_module():
    private = [f"{name}: {module}.{n}" for name, path in _modules().items() for module, names in _imports(path)
               for n in names if n.startswith("_") and n != "__version__"]
    assert private == []


MAX_FUNCTION_LINES = 60  # issue 11: a function a reader takes in at once; longer ones are split into named steps


def test_no_function_is_longer_than_60_lines():
    # a function's length: from its `def` line to its last line, docstring, comments and blank lines included
    # (what a reader scrolls through); nested functions count in their enclosing one and on their own
    long = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    long.append(f"{name}.{node.name}: {lines} lines")
    assert long == []


MAX_FILE_LINES = 450  # a module a reader can hold: past it, split by what the parts hold


def test_no_source_file_is_longer_than_450_lines():
    long = [f"{path.relative_to(PACKAGE).as_posix()}: {lines} lines" for path in sorted(PACKAGE.rglob("*.py"))
            if (lines := len(path.read_text().splitlines())) > MAX_FILE_LINES]
    assert long == []


# ---------------------------------------------------------------------------- the documents and the tool shelf
ROOT = Path(__file__).resolve().parents[1]
LAYOUT_ROW = re.compile(r"^\| [^|]+ \| (.+) \|$")
LAYOUT_PART = re.compile(r"`([\w/]+\.py)`: ([^;]+)")
NAME = re.compile(r"`([A-Za-z_][\w.]*)`")


def _lines(relative: str) -> int:
    return len((ROOT / relative).read_text().splitlines())


def test_the_readme_and_the_benchmarks_stay_short():
    assert _lines("README.md") <= 200
    assert _lines("docs/benchmarks.md") <= 150


def test_scripts_readme_names_every_script():
    listed = (ROOT / "scripts" / "README.md").read_text()
    missing = [p.name for p in sorted((ROOT / "scripts").iterdir())
               if p.is_file() and p.name != "README.md" and f"`{p.name}`" not in listed]
    assert not missing, f"scripts/README.md does not list {missing}"


def _layout_table() -> list[str]:
    text = (ROOT / "README.md").read_text().split("## Layout", 1)[1].split("\n## ", 1)[0]
    return [m.group(1) for line in text.splitlines() if (m := LAYOUT_ROW.match(line)) and "`" in line]


def _defined(source: Path) -> set[str]:
    """Names a file defines: its functions, classes and methods, and the names it assigns at any depth."""
    names = set()
    for node in ast.walk(ast.parse(source.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return names


def test_every_file_and_function_in_the_readmes_layout_exists():
    rows = _layout_table()
    assert len(rows) >= 12, "README's Layout has lost its map of the paper's concepts"
    for row in rows:
        for path, names in LAYOUT_PART.findall(row):
            source = PACKAGE / path
            assert source.is_file(), f"README's Layout names highway_srl/{path}, which does not exist"
            defined = _defined(source)
            for name in NAME.findall(names):
                assert set(name.split(".")) <= defined, f"README's Layout names {name} in {path}, not defined there"
