"""The package's layers (docs/development/architecture.md, "Layers"): imports point down,
and no import circles.

Every import of an ``orange_plan`` module counts, also one inside a function: a lazy import
still ties the two modules together.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
from conftest import REPO
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

PACKAGE = REPO / "orange_plan"


LAYERS_DOC = REPO / "docs" / "development" / "architecture.md"


def documented_layers() -> dict[str, int]:
    """Module or folder (``planning/``, ``cli.py``) -> layer number, from the layer table of
    the architecture page."""
    text = LAYERS_DOC.read_text(encoding="utf-8")
    section = text.split("## Layers", 1)[1].split("\n#", 1)[0]
    layers = {}
    for row in re.findall(r"^\| (\d+) \| ([^|]+) \|", section, flags=re.M):
        for name in re.findall(r"`([^`]+)`", row[1]):
            layers[name] = int(row[0])
    return layers


def module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def layer_of(module: str, layers: dict[str, int]) -> int | None:
    """The layer of a dotted module name (its folder's, or its own file's)."""
    parts = module.split(".")[1:]
    if not parts:
        return None  # the package's face
    return layers.get(parts[0] + "/") if len(parts) > 1 or f"{parts[0]}/" in layers \
        else layers.get(parts[0] + ".py")


MODULES = {module_name(p) for p in PACKAGE.rglob("*.py")}


def imports(path: Path) -> set[str]:
    """``orange_plan`` modules a file imports (anywhere in it)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(
                "orange_plan"):
            for alias in node.names:  # ``from package import module`` imports the module
                sub = f"{node.module}.{alias.name}"
                out.add(sub if sub in MODULES else node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("orange_plan"))
    return out


def edges() -> set[tuple[str, str]]:
    """(importer, imported) pairs of ``orange_plan`` modules."""
    return {(module_name(path), target) for path in PACKAGE.rglob("*.py")
            for target in imports(path)}


def test_every_module_has_a_layer_and_imports_point_down():
    layers = documented_layers()
    missing = sorted(m for m in MODULES if m != "orange_plan" and layer_of(m, layers) is None)
    assert not missing, f"modules on no layer of {LAYERS_DOC.name}: {missing}"
    upward = sorted((a, b) for a, b in edges() if "orange_plan" not in (a, b)
                    and layer_of(a, layers) < layer_of(b, layers))
    assert not upward, f"imports that point up a layer: {upward}"


def test_no_import_circles():
    faces = {module_name(p) for p in PACKAGE.rglob("__init__.py")}  # they only hand names on
    names = sorted(MODULES - faces)
    index = {m: i for i, m in enumerate(names)}
    pairs = [(index[a], index[b]) for a, b in edges() if a in index and b in index]
    graph = csr_matrix((np.ones(len(pairs)), tuple(np.array(pairs).T)),
                       shape=(len(names), len(names)))
    _, label = connected_components(graph, directed=True, connection="strong")
    circles = [[m for m, lab in zip(names, label) if lab == k]
               for k in np.flatnonzero(np.bincount(label) > 1)]
    assert not circles, f"modules importing each other in a circle: {circles}"


MAX_MODULE_LINES = 700


def test_every_module_is_short_enough_to_read():
    """No module of the package grows past 700 lines: a longer one holds more than one idea
    (split it by stage or by idea, as identify/diagnosis/ and planning/ do)."""
    too_long = {str(p.relative_to(REPO)): n for p in PACKAGE.rglob("*.py")
                if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not too_long, f"modules over {MAX_MODULE_LINES} lines: {too_long}"
