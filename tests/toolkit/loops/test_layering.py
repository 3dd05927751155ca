"""What the training loops share sits below them: toolkit's subpackages import one another without a cycle
(the avatar's training uses the Refiner and the Examiner; their loops use ``toolkit.loops``, not ``toolkit.train``)."""

from __future__ import annotations

from tests.imports_graph import cycle, graph


def subpackage(module: str) -> str:
    """``trioman.toolkit.refiner.loop`` -> ``trioman.toolkit.refiner``; a toolkit module is its own."""
    return ".".join(module.split(".")[:3])


def test_toolkit_subpackages_import_without_a_cycle():
    edges: dict[str, set[str]] = {}
    for module, targets in graph().items():
        if module.startswith("trioman.toolkit."):
            edges.setdefault(subpackage(module), set()).update(
                subpackage(t) for t in targets if t.startswith("trioman.toolkit.") and subpackage(t) != subpackage(module))
    for target in set().union(*edges.values()):
        edges.setdefault(target, set())
    found = cycle(edges)
    assert found is None, "import cycle between toolkit subpackages: " + " -> ".join(found)
