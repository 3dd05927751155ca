"""``trioman inspect PATH``: validate a subject folder and print a summary (no torch).

The library: trioman.runtime.formats.load_subject and trioman.runtime.inspect.summarize. An invalid
subject raises FormatError (a ValueError), which the CLI prints as one line before exiting with status 1.
Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", metavar="PATH", help="subject folder (subject.json, body.npz, frames.npz, images/, masks/)")
    parser.add_argument(
        "--no-images", action="store_true",
        help="skip the per-frame check that every image and mask exists with the right size",
    )


def run(args: argparse.Namespace) -> int:
    from trioman.runtime.formats import load_subject
    from trioman.runtime.inspect import summarize

    subject = load_subject(args.path, check_images=not args.no_images)
    for line in summarize(subject):
        print(line)
    print("valid" + ("" if not args.no_images else " (images not checked)"))
    return 0
