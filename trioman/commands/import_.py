"""``trioman import exavatar|smplx-fits``: real captures -> a subject folder (standard-library imports only here)."""

from __future__ import annotations

import argparse
from pathlib import Path


def _configs():
    from trioman.toolkit.importers.options import ExAvatarOptions, SmplxFitsOptions

    return ExAvatarOptions, SmplxFitsOptions


def flags() -> dict[str, str]:
    """The fields and parameters the library's errors (and its lines to ``say``) name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "overwrite": "--overwrite", "model_dir": "--body-model-dir",
            "masks_dir": "--masks"}


def _common_arguments(parser: argparse.ArgumentParser, options: type) -> None:
    from trioman.options import add_options

    parser.add_argument("--body-model-dir", required=True, metavar="DIR",
                        help="folder holding SMPLX_{NEUTRAL,MALE,FEMALE}.npz (licensed: https://smpl-x.is.tue.mpg.de)")
    add_options(parser, options)
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder at --out")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    exavatar_options, smplx_fits_options = _configs()
    sub = parser.add_subparsers(dest="source", metavar="SOURCE", required=True)
    ex = sub.add_parser("exavatar", help="a capture in ExAvatar's layout (X-Humans, NeuMan, custom video)")
    ex.add_argument("root", help="the dataset folder (e.g. data/XHumans/data) or the capture folder itself")
    ex.add_argument("--subject", default=None, metavar="ID", help="the capture under ROOT (e.g. 00028, bike)")
    ex.add_argument("--out", required=True, help="subject folder to write")
    _common_arguments(ex, exavatar_options)
    fits = sub.add_parser("smplx-fits", help="a video fitted with SMPL-X per frame (SMPLer-X's npz + meta json)")
    fits.add_argument("frames", help="folder of the video's frames (N.png or N.jpg)")
    fits.add_argument("fits", help="the fitter's output folder (smplx/FRAME_PERSON.npz and meta/FRAME_PERSON.json)")
    fits.add_argument("--out", required=True, help="subject folder to write")
    fits.add_argument("--masks", default=None, metavar="DIR", help="person masks, one PNG per frame (default FRAMES/../masks)")
    _common_arguments(fits, smplx_fits_options)


def _inputs(args: argparse.Namespace) -> list[Path]:
    """The folders an import reads: the capture; the frames, fits and masks folders."""
    if args.source == "exavatar":
        return [Path(args.root) / args.subject if args.subject else Path(args.root)]
    return [Path(args.frames), Path(args.fits), Path(args.masks) if args.masks else Path(args.frames).parent / "masks"]


def run(args: argparse.Namespace) -> int:
    from trioman.commands.flags import flag_message
    from trioman.options import given
    from trioman.runtime.formats.subject import SUBJECT_FOLDER
    from trioman.runtime.outputs import check_folder_target

    shown = flags()

    def say(line: str) -> None:
        print(flag_message(line, shown))

    exavatar_options, smplx_fits_options = _configs()
    options = exavatar_options if args.source == "exavatar" else smplx_fits_options
    cfg = options(**given(options, args))
    # before anything is read or the body-model stack imported: --out may not replace a foreign folder, nor be,
    # hold or lie inside the capture (docs/design.md, "What a command may delete, and what it may read")
    check_folder_target(Path(args.out), args.overwrite, SUBJECT_FOLDER, inputs=_inputs(args))
    if args.source == "exavatar":
        from trioman.toolkit.importers.exavatar import BodyConfig, import_exavatar

        body = BodyConfig(args.body_model_dir, cfg.gender, cfg.num_betas, cfg.flat_hand_mean)
        subject = import_exavatar(args.root, cfg.dataset, args.out, body, subject=args.subject,
                                  allow_pickle=cfg.allow_pickle, overwrite=args.overwrite, up=cfg.up,
                                  fits=cfg.fits, say=say)
    else:
        from trioman.toolkit.importers.smplx_fits import import_smplx_fits

        subject = import_smplx_fits(args.frames, args.fits, args.out, args.body_model_dir, masks_dir=args.masks,
                                    gender=cfg.gender, flat_hand_mean=cfg.flat_hand_mean,
                                    test_every=cfg.test_every, overwrite=args.overwrite, up=cfg.up, say=say)
    counts = {s: len(subject.indices(s)) for s in ("train", "test")}
    print(f"import: subject {subject.root}: {subject.num_frames} frames ({counts['train']} train, {counts['test']} test), "
          f"{subject.width}x{subject.height}, SMPL-X body ({subject.num_joints} joints)")
    return 0
