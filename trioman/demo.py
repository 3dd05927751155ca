"""The demo (``trioman demo``, ``run_demo``): the whole pipeline on the embedded synthetic subject, from
synthesis to an avatar trained with online augmentation; its stages, outputs and what it prints:
docs/demo.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from trioman.runtime.options import check_options, integer, number, option
from trioman.toolkit.synth.config import STYLES

if TYPE_CHECKING:
    from trioman.runtime.stages import StageLog
    from trioman.toolkit.train.config import TrainConfig


@dataclass(frozen=True)
class DemoConfig:
    out: str = option("out/demo", check=lambda v: None if isinstance(v, (str, Path)) and str(v) else "expected a folder path",
                      help="output folder: every stage's output goes in it")
    seed: int = option(0, check=integer(0), help="subject seed")
    style: str = option("realistic", choices=STYLES, help="the subject's look (trioman synth --style)")
    size: int = option(128, check=integer(16), help="image side in pixels (the shipped models' training size)")
    frames: int = option(96, check=integer(6), help="subject frames")
    coverage: float = option(0.33, metavar="FRACTION", check=number(0, 1, lo_open=True),
                             help="share of a full turn the training frames span (the regime the augmentation gain was "
                                  "measured in: the test views lie beyond it)")
    iterations: int = option(1000, check=integer(1), help="training iterations of both avatars, quick preset otherwise")
    augment_frames: int = option(24, check=integer(1), help="source frames to augment")
    progress: bool = True  # progress bars (on a terminal only)

    def __post_init__(self) -> None:
        check_options(self)
        if not isinstance(self.progress, bool):
            raise ValueError(f"progress: must be a bool, got {self.progress!r}")


def say(line: str) -> None:
    """Print one demo line now (stdout may be a file: ``make demo > log``)."""
    print(f"demo: {line}", flush=True)


def run_demo(cfg: DemoConfig) -> None:
    """The whole demo into ``cfg.out``, one line per stage, then the summary lines."""
    from trioman.toolkit.lpips import load_lpips_or_say_why
    from trioman.runtime.stages import StageLog, mib

    out = Path(cfg.out)
    progress = cfg.progress
    log = StageLog(say=say)
    lpips = load_lpips_or_say_why("demo")
    base = _baseline(cfg, out, log, lpips, progress)
    aug = _augment_stage(cfg, out, base["avatar_dir"], log, progress)
    final = _augmented_avatar(cfg, out, log, lpips, progress)
    with log.stage("novel views"):
        from trioman.toolkit.evaluate import comparison_grid

        final["grid"] = comparison_grid({"baseline": base["run"], "augmented": final["run"]}, "test",
                                        out / "novel_views.png")
    _report(base, aug, final)
    say(f"done in {log.seconds:.0f} s; peak RSS {mib(log.peak_rss):.0f} MiB (the highest stage)")


def _quick_preset(cfg: DemoConfig, **overrides: Any) -> TrainConfig:
    """The quick training preset with the demo's ``--iterations``."""
    from trioman.toolkit.train.config import preset

    return preset("quick", iterations=cfg.iterations, **overrides)


def _baseline(cfg: DemoConfig, out: Path, log: StageLog, lpips, progress: bool) -> dict:
    """Subject, turntable, baseline avatar, its evaluation, export and animations."""
    from trioman.export.avatar import export_avatar
    from trioman.runtime.animate import animate
    from trioman.runtime.outputs import remove_own
    from trioman.runtime.formats.motion import motion_from_spec
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.synth.turntable import write_turntable
    from trioman.toolkit.train.loop import RUN_FOLDER, train

    synth = SynthConfig(seed=cfg.seed, size=cfg.size, frames=cfg.frames, coverage=cfg.coverage, style=cfg.style)
    with log.stage("synth"):
        subject = synthesize_subject(synth, out / "subject", overwrite=True, progress=progress)
    with log.stage("turntable"):
        video = write_turntable(synth, out / "turntable.mp4", progress=progress)
    remove_own(out / "run", RUN_FOLDER)  # the demo always starts a fresh run (an earlier demo's, nothing else)
    train_cfg = _quick_preset(cfg)
    with log.stage("train"):
        run_dir = train(subject.root, out / "run", train_cfg, progress=progress, lpips=lpips)
    with log.stage("eval test"):
        test = evaluate(run_dir, "test", lpips=lpips, progress=progress)
    with log.stage("eval train"):
        seen = evaluate(run_dir, "train", lpips=lpips, progress=progress, video=False)
    avatar_dir = out / "avatar"
    with log.stage("export avatar"):
        avatar, _ = export_avatar(run_dir, avatar_dir, overwrite=True)
    with log.stage("animate"):
        anims = {name: animate(avatar, motion_from_spec(name, avatar.skeleton), out / f"animate_{name}.mp4",
                               camera=camera, size=cfg.size, progress=progress)
                 for name, camera in (("walk", "fixed"), ("wave", "orbit"))}
    return {"subject": subject, "turntable": video, "run": run_dir, "train_cfg": train_cfg, "test": test,
            "seen": seen, "avatar_dir": avatar_dir, "avatar": avatar, "anims": anims}


def _augment_stage(cfg: DemoConfig, out: Path, avatar_dir: Path, log: StageLog, progress: bool) -> dict:
    """Pseudo-GT frames of the first training frames by the torch-free runtime, with the shipped Refiner and
    Examiner (runtime/pretrained.py)."""
    from trioman.runtime.augment import augment
    from trioman.runtime.pretrained import SHIPPED

    with log.stage("augment"):
        result = augment(out / "subject", avatar_dir, SHIPPED, out / "augmented", SHIPPED, limit=cfg.augment_frames,
                         overwrite=True, progress=progress)
    return {"out": out / "augmented", "result": result}


def _augmented_avatar(cfg: DemoConfig, out: Path, log: StageLog, lpips, progress: bool) -> dict:
    """An avatar trained like the baseline with `--augment` (its default kind and the measured schedule), evaluated on
    the test split."""
    from trioman.runtime.outputs import remove_own
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.train.augment_config import ALONE, AugmentConfig
    from trioman.toolkit.train.loop import RUN_FOLDER, train

    run_aug = out / "run_augmented"
    remove_own(run_aug, RUN_FOLDER)
    train_cfg = _quick_preset(cfg, augment=AugmentConfig(mode=ALONE))
    with log.stage("train augmented"):
        train(out / "subject", run_aug, train_cfg, progress=progress, lpips=lpips)
    with log.stage("eval augmented"):
        test = evaluate(run_aug, "test", lpips=lpips, progress=progress)
    return {"run": run_aug, "test": test, "kind": train_cfg.augment.mode}


def _report(base: dict, aug: dict, final: dict) -> None:
    """Where the outputs are, and the test PSNR of both avatars."""
    subject, run_dir, train_cfg = base["subject"], base["run"], base["train_cfg"]
    say(f"subject       {subject.root} ({subject.num_frames} frames), contact sheet {subject.root / 'contact_sheet.png'}")
    say(f"turntable     {base['turntable']}")
    say(f"avatar run    {run_dir} ({train_cfg.iterations} iterations, {train_cfg.preset} preset)")
    for name, s in (("train", base["seen"]), ("test", base["test"])):
        m = s["mean"]
        say(f"{name:5s} frames  PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.4f} (masked protocol)  "
            f"report {run_dir / f'eval_{name}' / 'report.md'}")
    say(f"test grid     {run_dir / 'eval_test' / 'grid.png'}; video {run_dir / 'eval_test' / 'video.mp4'}")
    say(f"avatar        {base['avatar_dir']} ({base['avatar'].num_gaussians} Gaussians; canonical.ply opens in splat viewers)")
    for r in base["anims"].values():
        say(f"animation     {r['video']} ({r['frames']} frames, {r['ms_per_frame']:.0f} ms/frame with the numpy runtime)")
    s, t = aug["result"]["summary"], aug["result"]["timing"]["ms_per_source_frame"]
    say(f"pseudo-GT     {aug['out']} (trioman augment with the shipped Refiner and Examiner: {s['accepted']} frames "
        f"kept of {s['candidates']} candidates from {s['source_frames']} source frames, {t['total']:.0f} ms per source "
        f"frame; report {aug['out'] / 'augment.json'}, scores {aug['out'] / 'scores.png'})")
    before, after = base["test"]["mean"]["psnr"], final["test"]["mean"]["psnr"]
    say(f"augmented run {final['run']} (trioman train {subject.root} --augment: {final['kind']} pseudo-GT)")
    say(f"test PSNR (masked): baseline {before:.2f} dB, augmented {after:.2f} dB ({after - before:+.2f} dB, the same "
        f"{train_cfg.iterations} steps); report {final['run'] / 'eval_test' / 'report.md'}")
    say(f"novel views   {final['grid']} (test motions from views the capture did not see: GT | baseline | augmented)")
