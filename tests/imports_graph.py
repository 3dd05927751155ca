"""The import graph of the library and command modules, read with ``ast`` (imports inside functions too), and a
search for a cycle in it: tests/test_imports.py and tests/toolkit/loops/test_layering.py use them."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]
# Folder -> import name, top layer first (docs/design.md, "Layout and layering"). A module may import
# its own layer and the layers below it.
LAYERS = {"trioman": "trioman", "bench": "trioman.bench", "export": "trioman.export",
          "toolkit": "trioman.toolkit", "runtime": "trioman.runtime"}


class Import(NamedTuple):
    path: Path
    line: int
    module: str  # the importing module
    target: str  # the imported module
    name: str | None  # the imported name, for `from target import name`


def module_name(path: Path) -> str:
    """The import name of a library file: ``runtime/render/tiles.py`` -> ``trioman.runtime.render.tiles``."""
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [LAYERS[rel.parts[0]], *rel.parts[1:]]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> Iterator[Import]:
    """Every import in ``path``, at any depth, with relative imports resolved."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Import(path, node.lineno, module, alias.name, None)
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            target = ".".join(p for p in (base, node.module) if p)
            for alias in node.names:
                yield Import(path, node.lineno, module, target, alias.name)


def graph() -> dict[str, set[str]]:
    """Module -> the modules of ours it imports (``from package import module`` counts the module)."""
    paths = {module_name(p): p for folder in LAYERS for p in sorted((ROOT / folder).rglob("*.py"))}
    edges: dict[str, set[str]] = {m: set() for m in paths}
    for module, path in paths.items():
        for imp in imports(path):
            target = f"{imp.target}.{imp.name}" if f"{imp.target}.{imp.name}" in paths else imp.target
            if target in paths and target != module:
                edges[module].add(target)
    return edges


def cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (its modules, the first repeated at the end), or None."""
    done: set[str] = set()

    def visit(module: str, path: list[str]) -> list[str] | None:
        if module in path:
            return path[path.index(module):] + [module]
        if module in done:
            return None
        found = next(filter(None, (visit(t, path + [module]) for t in sorted(edges[module]))), None)
        done.add(module)
        return found

    return next(filter(None, (visit(m, []) for m in sorted(edges))), None)
