"""The ``trioman`` command: one entry point, one subcommand per job.

Each subcommand lives in its own module, ``trioman/commands/<name>.py``, exposing ``add_arguments(parser)``
and ``run(args) -> int``.
Those modules import only the standard library at module level, so ``trioman --help`` and every
runtime subcommand work where torch is not installed; a training subcommand checks its extra first.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import importlib.util
import os
import sys
from dataclasses import dataclass

from trioman import __version__
from trioman.commands.flags import command_flags, shown_message


@dataclass(frozen=True)
class Command:
    name: str
    module: str  # module with add_arguments(parser) and run(args)
    help: str
    extra: str | None = None  # pip extra whose packages the command needs, None for the runtime


# Order is the order shown by ``trioman --help``.
COMMANDS = (
    Command("demo", "trioman.commands.demo", "run the whole pipeline on the embedded synthetic subject", "train"),
    Command("synth", "trioman.commands.synth", "render a synthetic subject (monocular video + poses + cameras)", "train"),
    Command("train", "trioman.commands.train", "train a Gaussian avatar on a subject", "train"),
    Command("eval", "trioman.commands.eval", "evaluate a trained avatar: metrics, grid, video", "train"),
    Command("export", "trioman.commands.export", "export a trained avatar (portable folder) or the Refiner/Examiner (ONNX fp32/int8/fp16)", "train"),
    Command("fit", "trioman.commands.fit", "a person's video (or frames) -> a subject: the Anny body fitted on a CPU", "fit"),
    Command("import", "trioman.commands.import_", "import a real capture (ExAvatar layouts, SMPL-X fits) as a subject", "smplx"),
    Command("synth-corpus", "trioman.commands.synth_corpus", "synthetic subjects + baselines + triplets for the Refiner/Examiner", "train"),
    Command("triplets", "trioman.commands.triplets", "GT / coarse / normal-map triplets of a trained run", "train"),
    Command("train-refiner", "trioman.commands.train_refiner", "train the Refiner on a synthetic corpus", "train"),
    Command("train-examiner", "trioman.commands.train_examiner", "train the Examiner on a synthetic corpus", "train"),
    Command("animate", "trioman.commands.animate", "animate an exported avatar with a motion, as an MP4 (no torch)"),
    Command("render", "trioman.commands.render", "render one image of an exported avatar (no torch)"),
    Command("augment", "trioman.commands.augment", "pseudo-GT frames: Generator, Refiner, Examiner on an exported avatar (no torch)"),
    Command("view", "trioman.commands.view", "an avatar in the browser, posed live: motions, bends, subject cameras, augment outputs (no torch)", "viewer"),
    Command("inspect", "trioman.commands.inspect", "validate a subject folder and print a summary"),
    Command("bench", "trioman.commands.bench", "benchmarks: time and memory, written as markdown + JSON", "train"),
)

# The packages each extra brings, by import name: checked before a command of that extra runs.
EXTRA_IMPORTS = {"train": ("torch", "anny"), "smplx": ("torch", "smplx"), "viewer": ("viser",),
                 "fit": ("torch", "anny", "ai_edge_litert")}


class MissingExtraError(RuntimeError):
    pass


def require_extra(command: str, extra: str) -> None:
    """Raise a clear error naming the pip extra when its packages are not importable."""
    hint = f"pip install 'trioman[{extra}]'" + (" (CPU torch: pip install torch==2.13.0 first)"
                                                 if "torch" in EXTRA_IMPORTS[extra] else "")
    missing = [name for name in EXTRA_IMPORTS[extra] if importlib.util.find_spec(name) is None]
    if missing:
        raise MissingExtraError(
            f"'trioman {command}' needs the '{extra}' extra, and {', '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} not installed: {hint}")
    for name in EXTRA_IMPORTS[extra]:  # installed but broken (a partial install, a wrong build): one line too
        try:
            importlib.import_module(name)
        except Exception as err:  # noqa: BLE001 (any failure of a third-party import)
            first = (str(err).strip().splitlines() or [""])[0][:200]
            raise MissingExtraError(f"'trioman {command}' needs the '{extra}' extra, and {name} is installed but "
                                    f"fails to import ({type(err).__name__}: {first}): reinstall it, {hint}") from None


# The causes a user can act on, by errno; any other OSError shows its own strerror.
_OS_CAUSES = {
    errno.ENOSPC: "no space left on the device (the disk is full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.EISDIR: "is a directory (expected a file)",
    errno.ENOTDIR: "a part of the path is not a directory",
    errno.ENAMETOOLONG: "file name too long",
    errno.EIO: "input/output error (a failing disk or network file system)",
}


def describe_os_error(err: OSError) -> str:
    """One line naming the path and the cause of an OSError (an error raised with a message of our own,
    without errno, is shown as it is)."""
    if err.errno is None:
        return str(err)
    cause = _OS_CAUSES.get(err.errno, err.strerror or os.strerror(err.errno))
    paths = [os.fsdecode(p) for p in (err.filename, err.filename2) if p is not None]
    return f"{' -> '.join(paths)}: {cause}" if paths else f"{cause} (errno {err.errno})"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="trioman", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"trioman {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for cmd in COMMANDS:
        module = importlib.import_module(cmd.module)
        p = sub.add_parser(cmd.name, help=cmd.help, description=cmd.help)
        module.add_arguments(p)
        p.set_defaults(_command=cmd, _module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    cmd: Command = args._command
    try:
        if cmd.extra is not None:
            require_extra(cmd.name, cmd.extra)
        return int(args._module.run(args) or 0)
    except (MissingExtraError, ValueError, OSError, FloatingPointError) as err:
        # Expected user-facing failures: one clear line; TRIOMAN_DEBUG=1 shows the traceback.
        if os.environ.get("TRIOMAN_DEBUG"):
            raise
        message = describe_os_error(err) if isinstance(err, OSError) else str(err)
        message = shown_message(err, message, command_flags(args._module))  # parameters -> flags
        print(f"trioman {cmd.name}: error: {message}", file=sys.stderr)
        return 1
    except RecursionError:
        # An input nested deeper than Python's parsers recurse (a JSON file); the readers of
        # runtime.formats.common.read_json name the file, this is the net under the others.
        if os.environ.get("TRIOMAN_DEBUG"):
            raise
        print(f"trioman {cmd.name}: error: an input is nested too deeply to read (maximum recursion depth exceeded); "
              f"TRIOMAN_DEBUG=1 shows where", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"trioman {cmd.name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
