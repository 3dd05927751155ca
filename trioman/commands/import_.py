"""``trioman import exavatar|smplx-fits``: real captures -> a subject folder (standard-library imports only here)."""

from __future__ import annotations

import argparse
from pathlib import Path

# The parameters the library's errors (and its lines to ``say``) name -> the flags as typed; trioman/cli.py
# shows the errors with them (trioman/commands/flags.py).
FLAGS = {"overwrite": "--overwrite", "up": "--up", "fits": "--fits", "dataset": "--dataset",
         "allow_pickle": "--allow-pickle", "gender": "--gender", "num_betas": "--num-betas",
         "model_dir": "--body-model-dir", "masks_dir": "--masks", "test_every": "--test-every"}


def _body_arguments(parser: argparse.ArgumentParser, gender: str | None, num_betas: bool) -> None:
    parser.add_argument("--body-model-dir", required=True, metavar="DIR",
                        help="folder holding SMPLX_{NEUTRAL,MALE,FEMALE}.npz (licensed: https://smpl-x.is.tue.mpg.de)")
    parser.add_argument("--gender", default=gender, choices=("neutral", "male", "female"),
                        help=f"SMPL-X model (default {gender})" if gender else
                        "SMPL-X model (default: the fits' own: male, ExAvatar's; X-Humans' own fits: its gender.txt)")
    if num_betas:
        parser.add_argument("--num-betas", type=int, default=None,
                            help="shape coefficients (default: the fits' own: 100, ExAvatar's; X-Humans' own fits: "
                                 "its mean shape's 10)")
    parser.add_argument("--flat-hand-mean", action="store_true",
                        help="hand poses are absolute (default: relative to SMPL-X's hand mean, as smplx and ExAvatar use)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing subject folder at --out")
    parser.add_argument("--up", default="body", choices=("body", "cameras", "none"),
                        help="where the world's up comes from: the body's spine over the frames (default), the cameras' "
                             "mean up, or none (the capture's +y); the world is turned so the person stands along +z")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="source", metavar="SOURCE", required=True)
    ex = sub.add_parser("exavatar", help="a capture in ExAvatar's layout (X-Humans, NeuMan, custom video)")
    ex.add_argument("root", help="the dataset folder (e.g. data/XHumans/data) or the capture folder itself")
    ex.add_argument("--dataset", required=True, choices=("xhumans", "neuman", "custom"))
    ex.add_argument("--subject", default=None, metavar="ID", help="the capture under ROOT (e.g. 00028, bike)")
    ex.add_argument("--out", required=True, help="subject folder to write")
    ex.add_argument("--allow-pickle", action="store_true",
                    help="read pickled files (X-Humans' SMPLX/*.pkl fits); unpickling runs code, use only on files you trust")
    ex.add_argument("--fits", default="auto", choices=("auto", "exavatar", "xhumans"),
                    help="X-Humans: the fits to pose the body with: ExAvatar's fitting output of each take "
                         "(TAKE/smplx_optimized/smplx_params/, with its identity; 'exavatar' leaves out takes without "
                         "it), X-Humans' own SMPLX/*.pkl on X-Humans' own body (gender.txt, mean_shape_smplx.npy), or "
                         "auto (default): ExAvatar's when every take holds them, else X-Humans' own")
    _body_arguments(ex, None, num_betas=True)
    fits = sub.add_parser("smplx-fits", help="a video fitted with SMPL-X per frame (SMPLer-X's npz + meta json)")
    fits.add_argument("frames", help="folder of the video's frames (N.png or N.jpg)")
    fits.add_argument("fits", help="the fitter's output folder (smplx/FRAME_PERSON.npz and meta/FRAME_PERSON.json)")
    fits.add_argument("--out", required=True, help="subject folder to write")
    fits.add_argument("--masks", default=None, metavar="DIR", help="person masks, one PNG per frame (default FRAMES/../masks)")
    fits.add_argument("--test-every", type=int, default=5, help="every K-th frame is a test frame (default 5; 0: none)")
    _body_arguments(fits, "neutral", num_betas=False)


def _inputs(args: argparse.Namespace) -> list[Path]:
    """The folders an import reads: the capture; the frames, fits and masks folders."""
    if args.source == "exavatar":
        return [Path(args.root) / args.subject if args.subject else Path(args.root)]
    return [Path(args.frames), Path(args.fits), Path(args.masks) if args.masks else Path(args.frames).parent / "masks"]


def run(args: argparse.Namespace) -> int:
    from trioman.commands.flags import flag_message
    from trioman.runtime.formats.subject import SUBJECT_FOLDER
    from trioman.runtime.image_io import check_folder_target

    def say(line: str) -> None:
        print(flag_message(line, FLAGS))

    # before anything is read or the body-model stack imported: --out may not replace a foreign folder, nor be,
    # hold or lie inside the capture (docs/design.md, "What a command may delete, and what it may read")
    check_folder_target(Path(args.out), args.overwrite, SUBJECT_FOLDER, inputs=_inputs(args))
    if args.source == "exavatar":
        from trioman.toolkit.importers.exavatar import BodyConfig, import_exavatar

        body = BodyConfig(args.body_model_dir, args.gender, args.num_betas, args.flat_hand_mean)
        subject = import_exavatar(args.root, args.dataset, args.out, body, subject=args.subject,
                                  allow_pickle=args.allow_pickle, overwrite=args.overwrite, up=args.up,
                                  fits=args.fits, say=say)
    else:
        from trioman.toolkit.importers.smplx_fits import import_smplx_fits

        subject = import_smplx_fits(args.frames, args.fits, args.out, args.body_model_dir, masks_dir=args.masks,
                                    gender=args.gender, flat_hand_mean=args.flat_hand_mean,
                                    test_every=args.test_every, overwrite=args.overwrite, up=args.up, say=say)
    counts = {s: len(subject.indices(s)) for s in ("train", "test")}
    print(f"import: subject {subject.root}: {subject.num_frames} frames ({counts['train']} train, {counts['test']} test), "
          f"{subject.width}x{subject.height}, SMPL-X body ({subject.num_joints} joints)")
    return 0
