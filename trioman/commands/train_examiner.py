"""``trioman train-examiner --corpus DIR --out RUN``: train the Examiner on a synthetic corpus's
training subjects with the paper's pair targets (toolkit/corpus/training.py); resumes a run folder.
``--pairing paper`` draws the paper's 1/2 identical, 1/4 real, 1/4 coarse pairs at random; the
default "contrast" gives every sample its real and its coarse pair (toolkit/examiner/pairs.py).
``--validation-subjects N`` (default 1) holds the last N training subjects out and keeps the weights
of the step with the best AUROC on them (run/selected.pt). Under
``torchrun --nproc-per-node N -m trioman train-examiner ...`` the N processes train one run data-parallel
(docs/scaling.md): --batch is per process, rank 0 writes the run folder."""

from __future__ import annotations

import argparse

def _configs():
    from trioman.toolkit.corpus_training_options import TrainExaminerOptions

    return (TrainExaminerOptions,)


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "out": "--out"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("--corpus", required=True, help="corpus folder (trioman synth-corpus)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, fit.json)")
    add_options(parser, *_configs())


def run(args: argparse.Namespace) -> int:
    from trioman.options import given
    from trioman.toolkit.distributed import process_group
    from trioman.toolkit.corpus.training import examiner_fit, fit_examiner
    from trioman.toolkit.loops.checkpoint import ConfigMismatch

    (options,) = _configs()
    cfg = options(**given(options, args))
    with process_group(cfg.device) as ranks:
        try:
            _, info = fit_examiner(args.corpus, args.out, cfg.model, examiner_fit(cfg), cfg.pairing, cfg.validation_subjects,
                                   cfg.validate_every, device=cfg.device, mixed_precision=cfg.mixed_precision)
        except ConfigMismatch as err:
            raise err.with_hint(resume_hint(args, cfg, err)) from None
    if not ranks.main:
        return 0
    print(f"train-examiner: {info['checkpoint']} ({cfg.model}, {cfg.steps} steps, {info['seconds'] / 60:.1f} min, "
          f"final loss {info['final_loss']:.4f})")
    if info.get("selected_step") is not None:
        best = info["validation_auroc"][str(info["selected_step"])]
        print(f"train-examiner: kept step {info['selected_step']} (validation AUROC {best:.3f} on {cfg.validation_subjects} held-out subject(s))")
    return 0


def resume_hint(args: argparse.Namespace, cfg, err) -> str:
    """What resumes the run whose Examiner (``err``: a ConfigMismatch) differs from the one these options build:
    the command with the --model that builds the run's Examiner at the corpus's image size, when one does."""
    from trioman.commands import command_line
    from trioman.toolkit.examiner import EXAMINER_CONFIGS, examiner_config

    run, size = err.run_config, err.config.get("img_size")
    if run.get("img_size") != size:
        return (f"the run's Examiner sees {run.get('img_size')} px images, this corpus's are {size} px: resume it on the "
                f"corpus it was trained on, or choose another --out")
    for name in sorted(EXAMINER_CONFIGS, key=lambda name: name != cfg.model):
        if examiner_config(name, img_size=size).to_dict() == run:
            words = command_line("train-examiner", add_arguments, {**vars(args), "model": name})
            return f"resume it with the options it was started with: `{words}` (or choose another --out)"
    return ("no --model of this trioman builds the run's Examiner: resume it with the trioman version that started it, "
            "or choose another --out")
