"""``trioman train-refiner --corpus DIR --out RUN``: train the Refiner on a synthetic corpus's training
subjects (toolkit/corpus/training.py); resumes a run folder that has checkpoints. Under
``torchrun --nproc-per-node N -m trioman train-refiner ...`` the N processes train one run data-parallel
(docs/scaling.md): --batch is per process, rank 0 writes the run folder."""

from __future__ import annotations

import argparse

def _configs():
    from trioman.toolkit.corpus_training_options import TrainRefinerOptions

    return (TrainRefinerOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "pretrained_path": "--pretrained", "out": "--out"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--corpus", help="corpus folder (trioman synth-corpus): its training subjects' triplets")
    source.add_argument("--triplets", nargs="+", metavar="FILE",
                        help="triplet files instead (trioman triplets, e.g. --draws N ones of synthetic subjects)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, fit.json)")
    add_options(parser, *_configs())


def run(args: argparse.Namespace) -> int:
    from trioman.options import given
    from trioman.toolkit.distributed import process_group
    from trioman.toolkit.corpus.training import fit_refiner, refiner_fit
    from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, load_lpips
    from trioman.toolkit.loops.checkpoint import ConfigMismatch

    (options,) = _configs()
    cfg = options(**given(options, args))
    with process_group(cfg.device) as ranks:
        lpips = load_lpips()  # a named folder without the weights is an error before any work
        try:
            _, info = fit_refiner(args.corpus or args.triplets, args.out, cfg.conditions, refiner_fit(cfg), cfg.size, lpips=lpips,
                                  backbone=cfg.backbone, pretrained=cfg.pretrained, device=cfg.device,
                                  mixed_precision=cfg.mixed_precision, gradient_checkpointing=cfg.gradient_checkpointing)
        except ConfigMismatch as err:
            raise err.with_hint(resume_hint(args, cfg, err)) from None
    if not ranks.main:
        return 0
    if lpips is None:  # rank 0 alone says it, once the run has trained, never before an error
        print(f"train-refiner: {NOT_FOUND_MESSAGE}")
    print(f"train-refiner: {info['checkpoint']} ({cfg.conditions}, {cfg.steps} steps, {info['seconds'] / 60:.1f} min, "
          f"final loss {info['final_loss']:.4f})")
    return 0


def resume_hint(args: argparse.Namespace, cfg, err) -> str:
    """What resumes the run whose Refiner (``err``: a ConfigMismatch) differs from the one these options build:
    the command with the options that build the run's Refiner, when some do."""
    from trioman.commands import command_line
    from trioman.toolkit.corpus.training import REFINER_SIZES
    from trioman.toolkit.refiner import RefinerConfig

    run = err.run_config
    sizes = sorted(REFINER_SIZES, key=lambda name: name != cfg.size) if run.get("backbone") == "scratch" else [cfg.size]
    for size in sizes:  # the options that build a Refiner as fit_refiner does
        options = {"crop": run.get("image_size"), "conditions": run.get("conditions"), "backbone": run.get("backbone"),
                   "pretrained": run.get("pretrained_path"), "size": size}
        widths = REFINER_SIZES[size] if options["backbone"] == "scratch" else {}
        try:
            same = RefinerConfig(image_size=options["crop"], conditions=options["conditions"], backbone=options["backbone"],
                                 pretrained_path=options["pretrained"], **widths).to_dict() == run
        except (TypeError, ValueError):
            same = False
        if same:  # an option at its default that the user did not type is left out
            options = {k: None if getattr(args, k) is None and v == getattr(type(cfg), k) else v for k, v in options.items()}
            words = command_line("train-refiner", add_arguments, {**vars(args), **options})
            return f"resume it with the options it was started with: `{words}` (or choose another --out)"
    return ("no options of this trioman build the run's Refiner: resume it with the trioman version that started it, "
            "or choose another --out")
