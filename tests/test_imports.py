"""The architecture as a test: the layers of docs/design.md, no private names across modules, no import cycles.

Every import of every library and command module is read with ``ast``, those inside functions too.
import-linter cannot hold these rules here: its import graph (grimp) walks only top-level packages,
and setuptools' ``package-dir`` maps ``runtime/``, ``toolkit/``, ... into ``trioman`` from outside it.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

from tests.imports_graph import LAYERS, ROOT, Import, cycle, graph, imports

FORBIDDEN_EXTERNAL = {"trioman.runtime": ("torch",)}
# Heavy or optional packages -> the only packages or modules of ours that may import them: onnx builds the graphs
# (export; the runtime reads them with onnxruntime), matplotlib draws the benchmarks' figures, the body models and
# SD-Turbo each have their one loader.
ONLY_IN = {"onnx": ("trioman.export",), "matplotlib": ("trioman.bench",),
           "anny": ("trioman.toolkit.body.anny_model", "trioman.toolkit.fit"),
           "smplx": ("trioman.toolkit.body.smplx_model",), "diffusers": ("trioman.toolkit.refiner.sd_turbo",)}

# Violations that stay until their owner fixes them: "file:rule:imported" -> the reason. Fix one and
# remove its entry (a stale entry fails); a new entry needs a reason and a higher ceiling.
ALLOWED: dict[str, str] = {}
ALLOWED_CEILING = 0


def layer(module: str) -> int | None:
    """The layer index of one of our modules (0 = top), None for anything else."""
    if module.split(".")[0] != "trioman" or module == "trioman":  # the root package: __version__, under every layer
        return None
    return max(i for i, name in enumerate(LAYERS.values()) if within(module, name))


def is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def is_submodule(target: str, name: str) -> bool:
    """Whether ``from target import name`` imports a module (a file or a package of ours)."""
    folder, base = max(((f, n) for f, n in LAYERS.items() if within(target, n)), key=lambda fn: len(fn[1]))
    path = ROOT / folder / Path(*target[len(base):].split(".")) / name
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def violations(imp: Import) -> Iterator[tuple[str, str]]:
    """(rule, what) for each rule ``imp`` breaks."""
    own = layer(imp.module)
    for prefix, banned in FORBIDDEN_EXTERNAL.items():
        if (imp.module + ".").startswith(prefix + ".") and imp.target.split(".")[0] in banned:
            yield "forbidden", imp.target
    places = ONLY_IN.get(imp.target.split(".")[0])
    if places is not None and layer(imp.module) is not None and not any(within(imp.module, p) for p in places):
        yield "forbidden", imp.target
    if layer(imp.target) is None:
        return
    if layer(imp.target) < own:
        yield "layers", imp.target
    # A private module is private to its package; a private name to its module.
    parts = imp.target.split(".")
    if any(is_private(p) and not within(imp.module, ".".join(parts[:i])) for i, p in enumerate(parts)):
        yield "private", imp.target
    elif imp.name is not None and is_private(imp.name):
        if not (is_submodule(imp.target, imp.name) and within(imp.module, imp.target)):
            yield "private", f"{imp.target}.{imp.name}"


def found() -> dict[str, str]:
    """Every violation: "file:rule:imported" -> "file:line: message"."""
    out = {}
    for folder in LAYERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for imp in imports(path):
                for rule, what in violations(imp):
                    rel = path.relative_to(ROOT)
                    out.setdefault(f"{rel}:{rule}:{what}", f"{rel}:{imp.line}: {rule}: {imp.module} imports {what}")
    return out


def test_no_import_cycles():
    found = cycle(graph())
    assert found is None, "import cycle (imports inside functions count): " + " -> ".join(found)


def test_imports_keep_the_layers_and_private_names():
    bad = found()
    new = [msg for key, msg in bad.items() if key not in ALLOWED]
    assert not new, "import rules broken (docs/design.md, 'Layout and layering'):\n" + "\n".join(new)


def test_allowlist_only_shrinks():
    bad = found()
    stale = [key for key in ALLOWED if key not in bad]
    assert not stale, "fixed, remove from ALLOWED (and lower ALLOWED_CEILING):\n" + "\n".join(stale)
    assert len(ALLOWED) <= ALLOWED_CEILING


def test_the_rules_catch_what_they_should(tmp_path, monkeypatch):
    # A private module (none is left in the tree) in a copy of the layout: its package may import it.
    (tmp_path / "runtime" / "render").mkdir(parents=True)
    (tmp_path / "runtime" / "render" / "_hidden.py").touch()
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    runtime = ROOT / "runtime" / "avatar.py"
    checks = {
        ("trioman.torch", "torch", None): [],
        ("trioman.runtime.avatar", "torch.nn", None): [("forbidden", "torch.nn")],
        ("trioman.runtime.avatar", "trioman.toolkit.cpu", None): [("layers", "trioman.toolkit.cpu")],
        ("trioman.toolkit.cpu", "trioman.runtime.ply", "_x"): [("private", "trioman.runtime.ply._x")],
        ("trioman.bench.raster", "trioman.runtime.render._hidden", None):
            [("private", "trioman.runtime.render._hidden")],
        ("trioman.runtime.render", "trioman.runtime.render", "_hidden"): [],
        ("trioman.toolkit.cpu", "trioman.runtime.render", "_hidden"):
            [("private", "trioman.runtime.render._hidden")],
        ("trioman.cli", "trioman.bench.common", None): [],
        # The demo runs every layer, export included: it lives above them all (trioman/demo.py), not in toolkit.
        ("trioman.demo", "trioman.export.avatar", None): [],
        ("trioman.toolkit.demo", "trioman.export.avatar", None): [("layers", "trioman.export.avatar")],
        ("trioman.runtime.augment", "trioman", "__version__"): [],
        ("trioman.runtime.onnx_models", "onnx", None): [("forbidden", "onnx")],
        ("trioman.toolkit.train.loop", "matplotlib.pyplot", None): [("forbidden", "matplotlib.pyplot")],
        ("trioman.toolkit.synth.subject", "anny", None): [("forbidden", "anny")],
        ("trioman.toolkit.fit.fitter", "anny", None): [],
        ("trioman.export.onnx_models.graph", "onnx", None): [],
    }
    for (module, target, name), expected in checks.items():
        assert list(violations(Import(runtime, 1, module, target, name))) == expected, (module, target, name)
    assert cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None
