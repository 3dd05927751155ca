"""The ``trioman`` command: one entry point, one subcommand per job.

Each subcommand lives in a small module exposing ``add_arguments(parser)`` and ``run(args) -> int``.
Those modules import only the standard library at module level, so ``trioman --help`` and every
runtime subcommand work where torch is not installed; a training subcommand checks its extra first.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys
from dataclasses import dataclass

from trioman import __version__


@dataclass(frozen=True)
class Command:
    name: str
    module: str  # module with add_arguments(parser) and run(args)
    help: str
    extra: str | None = None  # pip extra whose packages the command needs, None for the runtime


# Order is the order shown by ``trioman --help``.
COMMANDS = (
    Command("demo", "trioman.toolkit.demo", "run the whole pipeline on the embedded synthetic subject", "train"),
    Command("synth", "trioman.toolkit.synth.command", "render a synthetic subject (monocular video + poses + cameras)", "train"),
    Command("train", "trioman.toolkit.train.command", "train a Gaussian avatar on a subject", "train"),
    Command("eval", "trioman.toolkit.eval_command", "evaluate a trained avatar: metrics, grid, video", "train"),
    Command("export", "trioman.export.command", "export a trained avatar (portable folder) or the Refiner/Examiner (ONNX fp32/int8/fp16)", "train"),
    Command("synth-corpus", "trioman.toolkit.corpus_command", "synthetic subjects + baselines + triplets for the Refiner/Examiner", "train"),
    Command("triplets", "trioman.toolkit.triplets_command", "GT / coarse / normal-map triplets of a trained run", "train"),
    Command("train-refiner", "trioman.toolkit.refiner_command", "train the Refiner on a synthetic corpus", "train"),
    Command("train-examiner", "trioman.toolkit.examiner_command", "train the Examiner on a synthetic corpus", "train"),
    Command("animate", "trioman.runtime.animate", "animate an exported avatar with a motion, as an MP4 (no torch)"),
    Command("render", "trioman.runtime.render_command", "render one image of an exported avatar (no torch)"),
    Command("augment", "trioman.runtime.augment_command", "pseudo-GT frames: Generator, Refiner, Examiner on an exported avatar (no torch)"),
    Command("inspect", "trioman.runtime.inspect", "validate a subject folder and print a summary"),
    Command("bench", "trioman.toolkit.bench", "benchmarks: time and memory, written as markdown + JSON", "train"),
)

# The packages each extra brings, by import name: checked before a command of that extra runs.
EXTRA_IMPORTS = {"train": ("torch", "anny")}


class MissingExtraError(RuntimeError):
    pass


def require_extra(command: str, extra: str) -> None:
    """Raise a clear error naming the pip extra when its packages are not importable."""
    missing = [name for name in EXTRA_IMPORTS[extra] if importlib.util.find_spec(name) is None]
    if missing:
        raise MissingExtraError(
            f"'trioman {command}' needs the '{extra}' extra, and {', '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} not installed: pip install 'trioman[{extra}]' "
            f"(CPU torch: pip install torch==2.13.0 first)"
        )


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
    except (MissingExtraError, ValueError, FileNotFoundError, FileExistsError, FloatingPointError) as err:
        # Expected user-facing failures: one clear line; TRIOMAN_DEBUG=1 shows the traceback.
        if os.environ.get("TRIOMAN_DEBUG"):
            raise
        print(f"trioman {cmd.name}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"trioman {cmd.name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
