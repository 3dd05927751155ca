"""``trioman export TARGET ...``: torch -> portable files (standard-library imports only here).

Targets: ``avatar`` (a run's checkpoint -> an avatar folder, docs/formats.md). Each target is a
sub-parser with its own arguments; ``run`` dispatches on ``args.target``.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    targets = parser.add_subparsers(dest="target", metavar="TARGET", required=True)
    p = targets.add_parser(
        "avatar", help="a trained run -> a portable avatar folder (gaussians, skeleton, pose-dependent ONNX, .ply)",
        description="Bake a trained avatar into a portable avatar folder that the runtime poses without torch "
                    "(docs/formats.md, 'Avatar').")
    p.add_argument("run", help="run folder written by trioman train")
    p.add_argument("--out", required=True, help="avatar folder to write")
    p.add_argument("--checkpoint", default=None, help="checkpoint file (default: the run's latest)")
    p.add_argument("--no-pose-dependent", action="store_true", help="leave out the pose-dependent terms (no ONNX graph)")
    p.add_argument("--ply-frame", type=int, action="append", default=[], metavar="I",
                   help="also write posed_I.ply at subject frame I's pose (repeatable)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")


def run(args: argparse.Namespace) -> int:
    if args.target == "avatar":
        return _run_avatar(args)
    raise ValueError(f"target: unknown export target {args.target!r}")


def _run_avatar(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.export.avatar import export_avatar

    avatar, info = export_avatar(args.run, args.out, checkpoint=args.checkpoint, pose_dependent=not args.no_pose_dependent,
                                 ply_frames=args.ply_frame, overwrite=args.overwrite)
    out = Path(args.out)
    total = sum(e["bytes"] for e in avatar.meta["files"].values())
    parity = info["onnx_parity_max_abs"]
    print(f"export: {avatar.num_gaussians} Gaussians, {avatar.skeleton.num_joints} joints, "
          f"{'anisotropic' if avatar.anisotropic else 'isotropic'}, pose-dependent "
          + (f"terms in {out / 'pose_dependent.onnx'} (max |onnxruntime - torch| {parity:.2g})" if parity is not None else "terms: none")
          + f", step {avatar.meta['source'].get('step')}, {info['seconds']:.1f} s")
    for name, entry in avatar.meta["files"].items():
        print(f"export:   {out / name}  ({entry['bytes'] / 1e6:.2f} MB)")
    print(f"export: avatar {out} ({total / 1e6:.2f} MB); load it with trioman.runtime.formats.load_avatar")
    return 0
