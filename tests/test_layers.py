"""The packages layer without cycles: checked on the source, every import statement included
(those inside functions too), so a lazy import cannot hide one.

Installed, the three folders are one namespace: edge/ is `edge_depth`, calibration/
`edge_depth.calibration`, tools/ `edge_depth.tools`; the layers are named by folder here.

    calibration   models, file formats, projection, the fits: imports nothing of edge
    edge.capture  readers and sources: never the writers (edge.mcap_log, edge.foxglove_msgs,
                  edge.ros2_log)
    edge.runtime  the engine: never torch, never the daemon or the network code

Data flows from the sensors' calibration into the pipeline, so `edge` depends on
`calibration` and never the other way round.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


FOLDERS = ("edge", "calibration", "tools")


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def as_folder(module: str) -> str:
    """An installed name in the repository's terms: edge_depth.calibration.io -> calibration.io,
    edge_depth.tools.train -> tools.train, edge_depth.cli -> edge.cli."""
    for folder in FOLDERS[1:]:  # the two mapped under edge_depth
        if module == f"edge_depth.{folder}" or module.startswith(f"edge_depth.{folder}."):
            return module[len("edge_depth."):]
    if module == "edge_depth" or module.startswith("edge_depth."):
        return "edge" + module[len("edge_depth"):]
    return module


def offenders(folder: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    found = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        bad = sorted(m for m in map(as_folder, imported_modules(path))
                     if any(m == f or m.startswith(f + ".") for f in forbidden))
        if bad:
            found[str(path.relative_to(ROOT))] = bad
    return found


@pytest.mark.parametrize("folder, forbidden", [
    ("calibration", ("edge", "tools")),
    ("edge/capture", ("edge.mcap_log", "edge.foxglove_msgs", "edge.ros2_log", "edge.daemon",
                      "edge.runner", "torch", "tools")),
    ("edge/runtime", ("torch", "edge.model", "edge.daemon", "edge.runner", "tools")),
    ("edge", ("tools",)),
])
def test_no_package_imports_a_layer_above_it(folder, forbidden):
    assert offenders(folder, forbidden) == {}


def test_every_import_of_ours_goes_through_the_installed_namespace():
    # `import calibration` works beside the repository and fails where the wheel is installed
    bare = {}
    for folder in FOLDERS + ("tests",):
        for path in sorted((ROOT / folder).rglob("*.py")):
            names = sorted(m for m in imported_modules(path)
                           if m.split(".")[0] in FOLDERS)
            if names:
                bare[str(path.relative_to(ROOT))] = names
    assert bare == {}


def test_the_check_sees_imports_inside_functions(tmp_path):
    module = tmp_path / "m.py"
    module.write_text("import os\n\ndef f():\n    from edge.cli import main\n    import torch\n")
    assert imported_modules(module) == {"os", "edge.cli", "torch"}


def module_graph() -> dict[str, set[str]]:
    """Each module of ours (`edge.cli`, `calibration.io`, `edge.capture` for a package's
    __init__) and the modules of ours it imports, function-level imports included; `from
    PACKAGE import NAME` counts NAME when it is a module."""
    modules = {}
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found = [as_folder(alias.name) for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                base = as_folder(node.module)
                found = [base] + [f"{base}.{alias.name}" for alias in node.names]
            else:
                continue
            targets.update(m for m in found if m in modules and m != name)
        graph[name] = targets
    return graph


def test_no_module_imports_one_that_imports_it_back():
    """No cycle between modules, however long, function-level imports included."""
    graph, state, cycles = module_graph(), {}, []

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycles.append(path[path.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert cycles == []


def test_the_cycle_check_finds_one(monkeypatch):
    import tests.test_layers as layers

    monkeypatch.setattr(layers, "module_graph", lambda: {"a": {"b"}, "b": {"c"}, "c": {"a"}})
    with pytest.raises(AssertionError, match=r"\['a', 'b', 'c', 'a'\]"):
        layers.test_no_module_imports_one_that_imports_it_back()
