"""``trioman inspect PATH``: validate a subject folder and print a summary (no torch).

The library: trioman.runtime.formats.load_subject and trioman.runtime.inspect.summarize. An invalid
subject raises FormatError (a ValueError), which the CLI prints as one line before exiting with status 1.
Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.runtime.inspect import InspectOptions

    return (InspectOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return option_flags(*_configs())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("path", metavar="PATH", help="subject folder (subject.json, body.npz, frames.npz, images/, masks/)")
    add_options(parser, *_configs())


def run(args: argparse.Namespace) -> int:
    from trioman.options import given
    from trioman.runtime.formats import load_subject
    from trioman.runtime.inspect import summarize

    (options,) = _configs()
    cfg = options(**given(options, args))
    subject = load_subject(args.path, check_images=cfg.check_images)
    for line in summarize(subject):
        print(line)
    print("valid" + ("" if cfg.check_images else " (images not checked)"))
    return 0
