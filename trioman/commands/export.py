"""``trioman export TARGET ...``: torch -> portable files (standard-library imports only here).

Targets: ``avatar`` (a run's checkpoint -> an avatar folder, docs/formats.md), ``onnx`` (the
Refiner and/or Examiner -> ONNX files for trioman.runtime.onnx_models, with int8/fp16 variants) and ``pretrained``
(an ``onnx`` folder's fp32 models -> the ones the package ships, runtime/pretrained.py). Each target is a
sub-parser with its own arguments; ``run`` dispatches on ``args.target``.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.export.config import AvatarExportOptions, OnnxExportOptions

    return AvatarExportOptions, OnnxExportOptions


def flags() -> dict[str, str]:
    """The fields and parameters the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "overwrite": "--overwrite", "out": "--out", "refiner": "--refiner",
            "examiner": "--examiner", "onnx_dir": "ONNX_DIR", "dest": "--dest", "heldout": "--heldout"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    avatar_options, onnx_options = _configs()
    targets = parser.add_subparsers(dest="target", metavar="TARGET", required=True)
    p = targets.add_parser(
        "avatar", help="a trained run -> a portable avatar folder (gaussians, skeleton, pose-dependent ONNX, .ply)",
        description="Bake a trained avatar into a portable avatar folder that the runtime poses without torch "
                    "(docs/formats.md, 'Avatar').")
    p.add_argument("run", help="run folder written by trioman train")
    p.add_argument("--out", required=True, help="avatar folder to write")
    p.add_argument("--checkpoint", default=None, help="checkpoint file (default: the run's latest)")
    add_options(p, avatar_options)
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")

    p = targets.add_parser(
        "onnx", help="the Refiner and/or Examiner -> ONNX files (fp32, int8, fp16) for the torch-free runtime",
        description="Export the Refiner and/or the Examiner as ONNX models that trioman.runtime.onnx_models loads "
                    "(docs/formats.md, 'ONNX models'): fp32 checked against torch, int8 variants gated on task "
                    "metrics (a failing one is REJECTED, not written), fp16 for GPUs. Writes export.json.")
    p.add_argument("--refiner", default=None, metavar="CKPT", help="Refiner checkpoint file or run folder (its latest checkpoint)")
    p.add_argument("--examiner", default=None, metavar="CKPT", help="Examiner checkpoint file or run folder (its latest checkpoint)")
    p.add_argument("--out", required=True, help="output folder to write")
    add_options(p, onnx_options)
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")

    p = targets.add_parser(
        "pretrained", help="an `export onnx` folder's fp32 Refiner and Examiner -> the models the package ships",
        description="Copy the fp32 refiner.onnx and examiner.onnx of a `trioman export onnx` folder into the "
                    "package's runtime/pretrained/ with models.json (sizes, sha256, parity): the models `trioman train "
                    "--augment` and `trioman augment` use by default (docs/models.md; `make models` runs the recipe).")
    p.add_argument("onnx_dir", metavar="ONNX_DIR", help="folder written by trioman export onnx (fp32 of both models)")
    p.add_argument("--dest", default=None, help="folder to write (default: the installed package's runtime/pretrained)")
    p.add_argument("--heldout", nargs="+", default=(), metavar="TRIPLETS.npz",
                   help="triplet files of subjects the models never saw: their quality there goes in the record")


def run(args: argparse.Namespace) -> int:
    if args.target == "avatar":
        return _run_avatar(args)
    if args.target == "onnx":
        return _run_onnx(args)
    if args.target == "pretrained":
        return _run_pretrained(args)
    raise ValueError(f"target: unknown export target {args.target!r}")


def _run_avatar(args: argparse.Namespace) -> int:
    from pathlib import Path

    from trioman.export.avatar import export_avatar
    from trioman.options import given

    options, _ = _configs()
    cfg = options(**given(options, args))
    avatar, info = export_avatar(args.run, args.out, checkpoint=args.checkpoint, pose_dependent=cfg.pose_dependent,
                                 ply_frames=cfg.ply_frames, overwrite=args.overwrite)
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


def _run_onnx(args: argparse.Namespace) -> int:
    if args.refiner is None and args.examiner is None:
        raise ValueError("export onnx: nothing to export: give --refiner CKPT and/or --examiner CKPT")
    from trioman.export.onnx_models import export_onnx, summary_lines
    from trioman.options import given

    _, options = _configs()
    cfg = options(**given(options, args))
    report = export_onnx(refiner=args.refiner, examiner=args.examiner, out=args.out, variants=cfg.variants,
                         calibration=cfg.calibration, size=cfg.size, overwrite=args.overwrite,
                         progress=lambda msg: print(f"export: {msg}", flush=True))
    for line in summary_lines(report):
        print(line)
    return 0


def _run_pretrained(args: argparse.Namespace) -> int:
    from trioman.export.pretrained import ship_pretrained
    from trioman.runtime.pretrained import PRETRAINED_DIR

    dest = args.dest or PRETRAINED_DIR
    record = ship_pretrained(args.onnx_dir, dest, heldout=args.heldout)
    for kind, e in record["models"].items():
        print(f"export: {kind:8s} {dest}/{e['file']} ({e['bytes'] / 1e6:.2f} MB, sha256 {e['sha256'][:12]}, "
              f"input {e['input_size']}, max |onnxruntime - torch| {e['parity_max_abs']:.2g})")
    if "heldout" in record:
        q = record["heldout"]
        print(f"export: held out ({q['test_frames']} test frames of {', '.join(q['subjects'])}): masked PSNR render "
              f"{q['psnr_render_db']:.2f} dB, refined {q['psnr_refined_db']:.2f} dB ({q['refiner_gain_db']:+.2f})"
              + (f", its aligned input {q['psnr_aligned_db']:.2f} dB (refined {q['refiner_gain_over_aligned_db']:+.2f})"
                 if "psnr_aligned_db" in q else "") + "; "
              f"Examiner AUROC real vs render {q['examiner_auroc_real_vs_render']:.3f}")
    print(f"export: record {dest}/models.json; the model card is docs/models.md")
    return 0
