"""``trioman bench TARGET``: benchmarks that write a markdown table and JSON to a folder, one module of
trioman.bench per target (``TARGETS``; each module's docstring says what it measures). Each target is a sub-parser
whose options are its config's fields (bench/config.py, bench/ablation_config.py), so its help shows its own
defaults. Timings are wall clock on the machine named in the report; nothing here is a timed test.
"""

from __future__ import annotations

import argparse
import dataclasses

# target -> (module, report function, markdown function, what it measures); the report function takes the target's
# config (``target_config``)
TARGETS = {
    "synth": ("trioman.bench.synth", "bench_synth", "synth_markdown", "time per stage and peak memory of synthesising "
              "a subject"),
    "train": ("trioman.bench.train", "bench_train", "train_markdown", "avatar quality against training time per preset, "
              "and where a training step's time goes"),
    "render": ("trioman.bench.render", "bench_render", "render_markdown", "the runtime renderer against the torch "
               "rasterizer and the oracle, by stage"),
    "models": ("trioman.bench.models", "bench_models", "models_markdown", "the Refiner and Examiner trained on a "
               "corpus, evaluated on held-out subjects"),
    "deploy": ("trioman.bench.deploy", "bench_deploy", "deploy_markdown", "error against run time of what the runtime "
               "deploys (renderer, ONNX models, augment)"),
    "ablation": ("trioman.bench.ablation", "bench_ablation", "ablation_markdown", "the paper's Tables 1 and 2 on "
                 "held-out synthetic subjects"),
    "frames": ("trioman.bench.frames", "bench_frames", "frames_markdown", "peak memory of training on a "
               "real-capture-sized subject"),
    "stability": ("trioman.bench.stability", "bench_stability", "stability_markdown", "the numerical-stability checks: "
                  "worst error and finiteness per case"),
    "scale": ("trioman.bench.scale", "bench_scale", "scale_markdown", "data-parallel training throughput at 1 and 2 "
              "processes"),
    "fit": ("trioman.bench.fit", "bench_fit", "fit_markdown", "trioman fit against the truth of realistic synthetic "
            "videos"),
    "landmarks": ("trioman.bench.landmarks", "bench_landmarks", "landmarks_markdown", "where MediaPipe's landmarks sit "
                  "on the Anny body"),
    "augment-cost": ("trioman.bench.augment_cost", "bench_augment_cost", "augment_cost_markdown", "the default "
                     "augmented run's wall time against the plain run's"),
}


def _target_configs() -> dict[str, type]:
    """Target -> its config class."""
    from trioman.bench import config
    from trioman.bench.ablation_config import AblationBenchConfig

    return {"synth": config.SynthBenchConfig, "train": config.TrainBenchConfig, "render": config.RenderBenchConfig,
            "models": config.ModelsBenchConfig, "deploy": config.DeployBenchConfig, "ablation": AblationBenchConfig,
            "frames": config.FramesBenchConfig, "stability": config.StabilityBenchConfig,
            "scale": config.ScaleBenchConfig, "fit": config.FitBenchConfig, "landmarks": config.LandmarksBenchConfig,
            "augment-cost": config.AugmentCostBenchConfig}


def _configs() -> tuple[type, ...]:
    """Every config whose options this command takes: the targets', the ablation's plan and its AugmentConfig."""
    from trioman.bench.ablation_config import AblationPlan
    from trioman.toolkit.train.augment_config import AugmentConfig

    return *_target_configs().values(), AblationPlan, AugmentConfig


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.bench.ablation_config import SCHEDULE, AblationPlan
    from trioman.runtime.options import flags as option_flags
    from trioman.toolkit.train.augment_config import AugmentConfig

    schedule = {name: flag for name, flag in option_flags(AugmentConfig).items() if name in SCHEDULE}
    return {**option_flags(*_target_configs().values(), AblationPlan), **schedule, "out": "--out",
            "pretrained_path": "--pretrained"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.bench.ablation_config import SCHEDULE, AblationPlan
    from trioman.bench.config import OUT
    from trioman.options import add_options
    from trioman.toolkit.train.augment_config import AugmentConfig

    configs = _target_configs()
    targets = parser.add_subparsers(dest="target", metavar="TARGET", required=True)
    for target, (*_, what) in TARGETS.items():
        p = targets.add_parser(target, help=what, description=f"trioman bench {target}: {what}.")
        p.add_argument("--out", default=OUT, metavar="DIR", help=f"report folder (default {OUT})")
        add_options(p, configs[target])
        if target == "ablation":
            add_options(p, AblationPlan)
            add_options(p, AugmentConfig, SCHEDULE)


def target_config(args: argparse.Namespace):
    """The config of ``args.target`` from the options given (the config's defaults for the others); the ablation's
    plan holds its own options and the AugmentConfig of its schedule's."""
    from trioman.options import given

    cls = _target_configs()[args.target]
    values = given(cls, args)
    if args.target == "ablation":
        from trioman.bench.ablation_config import SCHEDULE, AblationPlan
        from trioman.toolkit.train.augment_config import AugmentConfig

        schedule = AugmentConfig(**given(AugmentConfig, args, SCHEDULE))
        values["plan"] = AblationPlan(schedule=schedule, **given(AblationPlan, args))
    if "out" in {f.name for f in dataclasses.fields(cls)}:
        values["out"] = args.out
    return cls(**values)


def run(args: argparse.Namespace) -> int:
    import importlib

    from trioman.bench.common import machine, write_report
    from trioman.runtime.stages import lifetime_peak_rss_bytes, mib

    config = target_config(args)
    module, bench, markdown, _ = TARGETS[args.target]
    module = importlib.import_module(module)
    report = getattr(module, bench)(config)
    if args.target in ("models", "deploy", "ablation"):
        report["machine"], report["peak_rss_mib"] = machine(), mib(lifetime_peak_rss_bytes())
    md = getattr(module, markdown)(report)
    path = write_report(args.out, args.target, report, md)
    print(md)
    print(f"bench: report {path}")
    return 0
