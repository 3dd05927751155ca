"""``trioman demo``: the whole pipeline on the embedded synthetic subject (trioman.demo).

Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.demo import DemoConfig

    return (DemoConfig,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return option_flags(*_configs())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    add_options(parser, *_configs())
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from trioman.demo import DemoConfig, run_demo
    from trioman.options import given

    run_demo(DemoConfig(**given(DemoConfig, args), progress=not args.quiet))
    return 0
