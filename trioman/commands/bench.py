"""``trioman bench TARGET``: benchmarks that write a markdown table and JSON to a folder, one module of
trioman.bench per target (``TARGETS``; each module's docstring says what it measures). Timings are wall clock
on the machine named in the report; nothing here is a timed test.
"""

from __future__ import annotations

import argparse
import dataclasses

# target -> (module, report function, markdown function, config class); the report function takes the target's
# config (a frozen dataclass of the module, built by ``bench_config``)
TARGETS = {
    "synth": ("trioman.bench.synth", "bench_synth", "synth_markdown", "SynthBenchConfig"),
    "train": ("trioman.bench.train", "bench_train", "train_markdown", "TrainBenchConfig"),
    "render": ("trioman.bench.render", "bench_render", "render_markdown", "RenderBenchConfig"),
    "models": ("trioman.bench.models", "bench_models", "models_markdown", "ModelsBenchConfig"),
    "deploy": ("trioman.bench.deploy", "bench_deploy", "deploy_markdown", "DeployBenchConfig"),
    "ablation": ("trioman.bench.ablation", "bench_ablation", "ablation_markdown", "AblationBenchConfig"),
    "frames": ("trioman.bench.frames", "bench_frames", "frames_markdown", "FramesBenchConfig"),
    "stability": ("trioman.bench.stability", "bench_stability", "stability_markdown", "StabilityBenchConfig"),
    "scale": ("trioman.bench.scale", "bench_scale", "scale_markdown", "ScaleBenchConfig"),
    "fit": ("trioman.bench.fit", "bench_fit", "fit_markdown", "FitBenchConfig"),
    "landmarks": ("trioman.bench.landmarks", "bench_landmarks", "landmarks_markdown", "LandmarksBenchConfig"),
    "augment-cost": ("trioman.bench.augment_cost", "bench_augment_cost", "augment_cost_markdown", "AugmentCostBenchConfig"),
}
# The configs' fields the library's errors name: each the option of its name (``training``: --no-training) -> the flags
# as typed (trioman/commands/flags.py).
_FIELD_FLAGS = {name: "--" + name.replace("_", "-") for name in (
    "out", "size", "frames", "seed", "presets", "full_iterations", "eval_every", "avatar_run", "corpus", "subjects",
    "heldout", "refiner_steps", "refiner_size", "backbone", "pretrained", "crop", "examiner_steps", "batch",
    "baseline_frames", "examiner", "models", "repeats", "threads", "augment_frames", "seeds", "iterations",
    "detail_sigma", "coverage", "pose_noise", "reach", "augment_start", "augment_pool", "augment_refresh", "augment_mask",
    "variants", "ablation_subjects", "jobs", "style", "poses", "aspect", "focal", "avatar_iterations")} | {"training": "--no-training", "pretrained_path": "--pretrained"}


# AugmentConfig's options that bench ablation takes (its config's fields augment_<name>: the same flags).
ABLATION_AUGMENT = ("start", "refresh", "pool", "mask")


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags
    from trioman.toolkit.train.augment_config import AugmentConfig

    augment = {name: flag for name, flag in option_flags(AugmentConfig).items() if name in ABLATION_AUGMENT}
    return _FIELD_FLAGS | augment


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options
    from trioman.toolkit.train.augment_config import AugmentConfig

    parser.add_argument("target", choices=tuple(TARGETS), help="what to benchmark")
    parser.add_argument("--out", default="out/bench", help="report folder (default out/bench)")
    parser.add_argument("--size", type=int, default=None, help="image side (default: synth/train/render/deploy 256, models/ablation 128, frames 1024, scale 64; fit: the long side, 540; augment-cost: 128 and 256)")
    parser.add_argument("--frames", type=int, default=None, help="subject frames (default: synth 300, train 120, frames 1500, fit 375: a video of 300, augment-cost 96)")
    parser.add_argument("--seed", type=int, default=None, help="the subject's seed (default: fit 1004, the others 0)")
    parser.add_argument("--style", choices=("plain", "realistic"), default=None,
                        help="synth: the subject's style; ablation: the style of a corpus built here (default plain)")
    parser.add_argument("--avatar-iterations", type=int, default=None,
                        help="fit: > 0 also trains the avatar on the fit and on the true poses this long (the cost of fitting)")
    parser.add_argument("--focal", choices=("prior", "truth"), default=None,
                        help="fit: the fit refines a phone's focal (prior, default) or is given the subject's (truth)")
    parser.add_argument("--aspect", type=float, default=None, metavar="W/H",
                        help="synth: image width / height, e.g. 0.5625 for a portrait phone video (default 1)")
    parser.add_argument("--presets", default="quick,full", help="train: presets to run, comma-separated")
    parser.add_argument("--full-iterations", type=int, default=None, help="train: cap the full preset's iterations")
    parser.add_argument("--eval-every", type=int, default=250, help="train: test evaluation interval (iterations)")
    parser.add_argument("--no-training", action="store_true", help="train: only the rasterizer timings; ablation: report the finished runs, train nothing")
    parser.add_argument("--avatar-run", default=None, metavar="RUN",
                        help="render: a trained run folder (default: the untrained default avatar)")
    parser.add_argument("--corpus", default="out/corpus", help="models: corpus folder, built when absent (default out/corpus)")
    parser.add_argument("--subjects", type=int, default=None,
                        help="models/ablation: training subjects when building the corpus (default 10); fit: subjects (default 3)")
    parser.add_argument("--heldout", type=int, default=None,
                        help="models/ablation: held-out subjects when building the corpus (default models 2, ablation 3)")
    parser.add_argument("--refiner-steps", type=int, default=1000, help="models: Refiner training steps per condition")
    parser.add_argument("--refiner-size", choices=("compact", "default"), default="compact", help="models: Refiner widths")
    parser.add_argument("--backbone", choices=("scratch", "sd-turbo"), default="scratch", help="models: the Refiner's backbone")
    parser.add_argument("--pretrained", metavar="DIR", help="models: local SD-Turbo folder for --backbone sd-turbo (never downloaded)")
    parser.add_argument("--crop", type=int, default=64, help="models: Refiner training crop side (default 64)")
    parser.add_argument("--examiner-steps", type=int, default=1000, help="models: Examiner training steps")
    parser.add_argument("--batch", type=int, default=4, help="models: training batch size; scale: samples per process and step")
    parser.add_argument("--baseline-frames", default="all",
                        help="models: corpus variants for the coarse frames, e.g. all,subset (each extra one adds a tex+geo Refiner); "
                             "ablation: the one variant its Refiners and Examiner train on")
    parser.add_argument("--examiner", default="examiner_nano", help="models: Examiner config name (default examiner_nano)")
    parser.add_argument("--models", default="out/bench_models",
                        help="deploy: the `bench models` report folder whose trained runs are exported (default out/bench_models)")
    parser.add_argument("--repeats", type=int, default=5, help="deploy: timed calls per variant (the best counts); train: timed steps of the step profile")
    parser.add_argument("--threads", type=int, default=None, help="deploy: onnxruntime intra-op threads (default: ORT's); train: the step profile's torch threads (default 1 and 2)")
    parser.add_argument("--augment-frames", type=int, default=8, help="deploy: source frames of the augment run")
    parser.add_argument("--seeds", type=int, default=2, help="ablation: seeds of the baseline and the full system (default 2); stability: extreme scenes drawn")
    parser.add_argument("--iterations", type=int, default=None,
                        help="train: every preset's iterations; ablation: real-frame steps of every avatar run (default 600); "
                             "frames: training iterations (default 20); stability: training steps per case (default 30); "
                             "scale: timed steps per series (default 20); augment-cost: steps of each run (default 300)")
    parser.add_argument("--detail-sigma", type=float, default=None, metavar="PX",
                        help="ablation: also train the lever GRd_tex+geo, refined pseudo-GT keeping only the Refiner's detail "
                             "(its change minus that change blurred by PX pixels)")
    parser.add_argument("--coverage", type=float, default=None, metavar="FRACTION",
                        help="ablation: re-render the held-out subjects with their training turn spanning this share of "
                             "a full turn (default 1: the corpus's subjects)")
    parser.add_argument("--pose-noise", type=float, default=None, metavar="DEG",
                        help="ablation: re-render the held-out subjects with this fitting noise on their stored poses "
                             "(evaluated at the true test poses; default 0)")
    parser.add_argument("--poses", choices=("true", "fit"), default=None,
                        help="ablation: the held-out subjects' poses: true (with --pose-noise) or fit (each re-rendered as a "
                             "video, every frame, and fitted by `trioman fit`; evaluated at the fitted test poses; default true)")
    parser.add_argument("--reach", type=float, default=None, metavar="FACTOR",
                        help="ablation: the Generator's camera sigmas (azimuth, elevation, log-distance) as a multiple of "
                             "their defaults (default 1)")
    add_options(parser, AugmentConfig, ABLATION_AUGMENT, prefix="ablation: ")
    parser.add_argument("--variants", default=None, metavar="NAMES",
                        help="ablation: train only these rows (comma-separated); the others are reported when finished")
    parser.add_argument("--ablation-subjects", default=None, metavar="NAMES",
                        help="ablation: comma-separated held-out subjects of the corpus (default: all of them)")
    parser.add_argument("--jobs", type=int, default=None,
                        help="ablation: avatar runs trained at once, each in its own process with an equal share of the "
                             "cores (default 1)")


def bench_config(cls: type, args: argparse.Namespace):
    """A target's config ``cls`` from the parsed options: each field from the option of its name (for a tuple of
    names, a comma-separated list, empty names dropped; ``training`` is not --no-training); an option left unset
    (None) keeps the field's default."""
    values = {}
    for field in dataclasses.fields(cls):
        value = not args.no_training if field.name == "training" else getattr(args, field.name)
        if value is not None:
            names = str(field.type).startswith("tuple[str")
            values[field.name] = tuple(v for v in value.split(",") if v) if names else value
    return cls(**values)


def run(args: argparse.Namespace) -> int:
    import importlib

    from trioman.bench.common import machine, peak_rss_mib, write_report

    module, bench, markdown, config = TARGETS[args.target]
    module = importlib.import_module(module)
    report = getattr(module, bench)(bench_config(getattr(module, config), args))
    if args.target in ("models", "deploy", "ablation"):
        report["machine"], report["peak_rss_mib"] = machine(), peak_rss_mib()
    md = getattr(module, markdown)(report)
    path = write_report(args.out, args.target, report, md)
    print(md)
    print(f"bench: report {path}")
    return 0
