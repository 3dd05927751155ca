"""``trioman train-examiner --corpus DIR --out RUN``: train the Examiner on a synthetic corpus's
training subjects with the paper's pair targets (toolkit/model_training.py); resumes a run folder.
``--pairing paper`` draws the paper's 1/2 identical, 1/4 real, 1/4 coarse pairs at random; the
default "contrast" gives every sample its real and its coarse pair (toolkit/examiner/pairs.py).
``--validation-subjects N`` (default 1) holds the last N training subjects out and keeps the weights
of the step with the best AUROC on them (run/selected.pt). Under
``torchrun --nproc-per-node N -m trioman train-examiner ...`` the N processes train one run data-parallel
(docs/scaling.md): --batch is per process, rank 0 writes the run folder."""

from __future__ import annotations

import argparse

# The parameters the library's errors name -> the flags as typed (trioman/commands/flags.py).
FLAGS = {"device": "--device", "baseline_frames": "--baseline-frames"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--corpus", required=True, help="corpus folder (trioman synth-corpus)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, fit.json)")
    parser.add_argument("--model", default="examiner_nano", help="config name: examiner_nano, examiner_tiny, examiner_small")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--batch", type=int, default=4,
                        help="samples per process and step (default 4; the global batch is this times the process count)")
    parser.add_argument("--baseline-frames", choices=("all", "subset"), default="all", help="corpus variant")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pairing", choices=("contrast", "paper"), default="contrast",
                        help="training pairs: every sample's real and coarse pair (default), or the paper's random draw")
    parser.add_argument("--validation-subjects", type=int, default=1,
                        help="hold out the last N training subjects and keep the step with the best AUROC on them (0: last step)")
    parser.add_argument("--validate-every", type=int, default=100, help="steps between validations")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cpu or cuda (under torchrun each process takes the GPU of its local rank; default cpu)")
    parser.add_argument("--mixed-precision", choices=("no", "bf16"), default="no", help="bf16 autocast (CUDA)")


def run(args: argparse.Namespace) -> int:
    from trioman.toolkit.distributed import process_group
    from trioman.toolkit.model_training import FitConfig, fit_examiner
    from trioman.toolkit.loops.checkpoint import ConfigMismatch

    fit = FitConfig(steps=args.steps, batch=args.batch, lr=3e-4, crop=None, seed=args.seed, baseline_frames=args.baseline_frames)
    with process_group(args.device) as ranks:
        try:
            _, info = fit_examiner(args.corpus, args.out, args.model, fit, args.pairing, args.validation_subjects,
                                   args.validate_every, device=args.device, mixed_precision=args.mixed_precision)
        except ConfigMismatch as err:
            raise err.with_hint(resume_hint(args, err)) from None
    if not ranks.main:
        return 0
    print(f"train-examiner: {info['checkpoint']} ({args.model}, {args.steps} steps, {info['seconds'] / 60:.1f} min, "
          f"final loss {info['final_loss']:.4f})")
    if info.get("selected_step") is not None:
        best = info["validation_auroc"][str(info["selected_step"])]
        print(f"train-examiner: kept step {info['selected_step']} (validation AUROC {best:.3f} on {args.validation_subjects} held-out subject(s))")
    return 0


def resume_hint(args: argparse.Namespace, err) -> str:
    """What resumes the run whose Examiner (``err``: a ConfigMismatch) differs from the one these options build:
    the command with the --model that builds the run's Examiner at the corpus's image size, when one does."""
    from trioman.commands import command_line
    from trioman.toolkit.examiner import EXAMINER_CONFIGS, examiner_config

    run, size = err.run_config, err.config.get("img_size")
    if run.get("img_size") != size:
        return (f"the run's Examiner sees {run.get('img_size')} px images, this corpus's are {size} px: resume it on the "
                f"corpus it was trained on, or choose another --out")
    for name in sorted(EXAMINER_CONFIGS, key=lambda name: name != args.model):
        if examiner_config(name, img_size=size).to_dict() == run:
            words = command_line("train-examiner", add_arguments, {**vars(args), "model": name})
            return f"resume it with the options it was started with: `{words}` (or choose another --out)"
    return ("no --model of this trioman builds the run's Examiner: resume it with the trioman version that started it, "
            "or choose another --out")
