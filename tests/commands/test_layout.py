"""Every subcommand in trioman/commands/<name>.py; no command-line code in the library."""

import ast
import importlib
from pathlib import Path

from tests.conftest import run_python
from trioman.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ("runtime", "toolkit", "export", "bench")
LIBRARY_IN_THE_COMMAND_PACKAGE = ("trioman/demo.py",)  # trioman demo's library (docs/design.md, "Layout and layering")
THIRD_PARTY = ("numpy", "torch", "onnx", "onnxruntime", "cv2", "trioman")


def test_each_command_in_its_module():
    for cmd in COMMANDS:
        name = cmd.name.replace("-", "_") + ("_" if cmd.name == "import" else "")
        assert cmd.module == f"trioman.commands.{name}", cmd
        module = importlib.import_module(cmd.module)
        assert callable(module.add_arguments) and callable(module.run)


def test_command_modules_import_only_the_standard_library_at_module_level():
    for path in sorted((ROOT / "trioman" / "commands").glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ImportFrom):
                assert node.level == 0 and node.module.split(".")[0] not in THIRD_PARTY, (path.name, node.module)
            elif isinstance(node, ast.Import):
                assert not any(a.name.split(".")[0] in THIRD_PARTY for a in node.names), path.name


def test_library_modules_hold_no_command_line_code():
    library = [p for folder in LIBRARY for p in sorted((ROOT / folder).rglob("*.py"))]
    for path in library + [ROOT / name for name in LIBRARY_IN_THE_COMMAND_PACKAGE]:
        tree = ast.parse(path.read_text())
        names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert not {"add_arguments", "run"} <= names, path.relative_to(ROOT)
        assert "argparse.ArgumentParser" not in path.read_text(), path.relative_to(ROOT)


def test_runtime_commands_import_without_torch():
    runtime = [c.module for c in COMMANDS if c.extra is None]
    proc = run_python("import importlib, sys\n"
                      f"for name in {runtime!r}:\n"
                      "    importlib.import_module(name).run\n"
                      "print('ok')", block_torch=True)
    assert proc.returncode == 0, proc.stderr
