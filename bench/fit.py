"""``trioman bench fit``: ``trioman fit`` on held-out synthetic subjects rendered as the video a user would have
(``trioman synth --style realistic --video``), against their truth: pose error (MPJPE after root alignment and
PA-MPJPE after Procrustes, per joint group), the person masks against the true ones, frames dropped, time per
frame and peak memory."""

from __future__ import annotations

import time
from pathlib import Path

from trioman.bench.common import machine
from trioman.bench.config import FitBenchConfig
from trioman.runtime.stages import lifetime_peak_rss_bytes, mib

TARGETS = {"pa_mpjpe_mm": 40.0, "seconds_per_300_frames": 300.0, "peak_rss_mib": 3072.0, "cost_of_fitting_db": 1.0}


# the cost-of-fitting runs: what each avatar is trained on
LABELS = {"fitted": "the fitted poses", "refined": "the fitted poses, refined", "true": "the true poses",
          "true_video": "the true poses and the video's frames"}


def say(line: str) -> None:
    """One line per finished step, so that a logged run is never silent for minutes."""
    print(f"bench fit: {line}", flush=True)


def bench_fit(config: FitBenchConfig) -> dict:
    import dataclasses
    import json

    from trioman.runtime.formats import load_subject
    from trioman.toolkit.fit.evaluate import compare
    from trioman.toolkit.fit.fitter import FitConfig
    from trioman.toolkit.fit.run import FitRunConfig, fit_video
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject

    work = Path(config.out) / "fit_work"
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for k in range(config.subjects):
        seed = config.seed + k
        truth_dir, video, fit_dir = work / f"s{seed}", work / f"s{seed}.mp4", work / f"s{seed}_fit"
        if not (truth_dir / "subject.json").is_file() or not video.is_file():
            t = time.perf_counter()
            synthesize_subject(SynthConfig(seed=seed, size=config.size, frames=config.frames, aspect=9 / 16,
                                           coverage=config.coverage, capture=config.capture, style=config.style), truth_dir, overwrite=True,
                               progress=False, video=video)
            say(f"{truth_dir.name}: subject and video rendered ({time.perf_counter() - t:.0f} s)")
        truth = load_subject(truth_dir)
        fit_cfg = FitConfig() if config.iterations is None else FitConfig(all_iterations=config.iterations,
                                                                          key_iterations=max(40, config.iterations))
        cfg = FitRunConfig(focal=float(truth.K[0, 0, 0]) if config.focal == "truth" else None, fit=fit_cfg)
        t = time.perf_counter()
        fitted = fit_video(video, fit_dir, cfg, overwrite=True, progress=False, say=lambda line: None)
        seconds = time.perf_counter() - t
        report = json.loads((fit_dir / "fit.json").read_text())
        scores = compare(fitted, truth)
        say(f"{truth_dir.name}: fitted ({seconds:.0f} s): PA-MPJPE {scores['pa_mpjpe']} mm")
        read = report["summary"]["frames_read"]
        rows.append({"subject": truth_dir.name, "frames_read": read, "frames_kept": report["summary"]["frames_kept"],
                     "dropped": report["summary"]["dropped"], **{k: v for k, v in scores.items() if k != "per_frame_pa_mpjpe_mm"},
                     "reprojection_px": report["summary"]["reprojection_px_mean"],
                     "body_mask_iou": report["summary"]["mask_iou_mean"], "focal_px": report["camera"]["focal_px"],
                     "true_focal_px": round(float(truth.K[0, 0, 0]), 1), "seconds": round(seconds, 1),
                     "seconds_per_300_frames": round(300 * seconds / max(read, 1), 1),
                     **(_cost_of_fitting(fitted, truth, work / f"s{seed}", config.avatar_iterations)
                        if config.avatar_iterations else {})})
    return {"target": "fit", "machine": machine(), "config": {k: str(v) if isinstance(v, Path) else v
                                                             for k, v in dataclasses.asdict(config).items()},
            "rows": rows, "peak_rss_mib": round(mib(lifetime_peak_rss_bytes()), 1), "targets": TARGETS}


def _cost_of_fitting(fitted, truth, stem: Path, iterations: int) -> dict:
    """The same avatar (quick preset, ``iterations``) trained on the fitted subject, on it with pose corrections
    learnt (``refine_poses``), on its twin made of the truth's frames, poses, cameras and masks (the same frames and
    split), and on the twin made of the fitted subject's own frames and masks (decoded from the video, cut by the
    person model's mask) with the truth's poses and cameras: what the video's frames cost apart from the poses. Each
    is evaluated on its own test frames (held-out video frames: the fitted ones at fitted poses, as a user's are; the
    refined run's at the poses it corrected, from no test pixel), and again at its test poses refitted to their own
    pixels (``poses="optimised"``). -> masked test PSNRs and the differences."""
    from trioman.runtime.formats import save_subject
    from trioman.toolkit.corpus.build import finished
    from trioman.toolkit.evaluate import evaluate
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train

    idx = [list(truth.frame_names).index(n) for n in fitted.frame_names]

    def twin(path: Path, source, rows: list[int]) -> Path:
        """The truth's poses and cameras with ``source``'s frames and masks ``rows``."""
        save_subject(path, body=truth.body, poses=truth.poses_true[idx], trans=truth.trans[idx], K=truth.K[idx],
                     viewmat=truth.viewmat[idx], split=list(fitted.split), sequence=list(fitted.sequence),
                     images=(source.image(i) for i in rows), masks=(source.mask(i) for i in rows), width=truth.width,
                     height=truth.height, body_model=truth.body_model, background=(0.0, 0.0, 0.0),
                     phenotype=truth.meta["phenotype"], generator={"tool": "trioman bench fit", "twin_of": truth.root.name},
                     frame_names=list(fitted.frame_names), overwrite=True)
        return path

    subjects = {"fitted": (fitted.root, False), "refined": (fitted.root, True),
                "true": (twin(Path(f"{stem}_true_poses"), truth, idx), False),
                "true_video": (twin(Path(f"{stem}_true_poses_video_frames"), fitted, list(range(len(idx)))), False)}
    psnr, refitted = {}, {}
    for name, (subject, refine) in subjects.items():
        run = Path(f"{stem}_avatar_{name}")
        t = time.perf_counter()
        if not finished(run, iterations):  # a finished run (the fit is seeded: the same subject) is only evaluated
            train(subject, run, preset("quick", iterations=iterations, checkpoint_every=iterations, refine_poses=refine),
                  resume=(run / "config.json").is_file(), progress=False)
        psnr[name] = round(float(evaluate(run, "test", progress=False, video=False, grid_frames=3)["mean"]["psnr"]), 2)
        refitted[name] = round(float(evaluate(run, "test", out=run / "eval_test_optimised", progress=False, video=False,
                                              grid_frames=3, poses="optimised")["mean"]["psnr"]), 2)
        say(f"{stem.name}: avatar on {LABELS[name]}: {psnr[name]} dB, {refitted[name]} at test poses refitted to their "
            f"pixels ({time.perf_counter() - t:.0f} s)")
    return {"psnr_fitted_poses": psnr["fitted"], "psnr_refined_poses": psnr["refined"], "psnr_true_poses": psnr["true"],
            "psnr_true_poses_video_frames": psnr["true_video"],
            "cost_of_fitting_db": round(psnr["true"] - psnr["fitted"], 2),
            "cost_refined_db": round(psnr["true"] - psnr["refined"], 2),
            "cost_of_the_frames_db": round(psnr["true"] - psnr["true_video"], 2),
            **{f"psnr_{k}_refitted": v for k, v in refitted.items()},
            **{f"cost_{arm}_refitted{vs}_db": round(refitted[twin] - refitted[arm], 2) for arm in ("fitted", "refined")
               for twin, vs in (("true", ""), ("true_video", "_same_frames"))}}


def fit_markdown(r: dict) -> str:
    c = r["config"]
    lines = [
        f"# trioman bench fit ({c['style']} subjects, long side {c['size']} px, 9:16, capture: {c['capture']}, "
        f"coverage {c['coverage']:g}, focal: {c['focal']})", "",
        f"Machine: {r['machine']}. Command: `trioman bench fit --seed {c['seed']} --subjects {c['subjects']} "
        f"--size {c['size']} --frames {c['frames']} --capture {c['capture']} --coverage {c['coverage']:g} "
        f"--style {c['style']} --focal {c['focal']}`. Each subject is rendered with "
        f"`trioman synth --style {c['style']} --aspect 9:16 --capture {c['capture']} --coverage {c['coverage']:g} "
        "--video`, fitted from the video alone by `trioman fit`, and "
        "compared with the truth on the frames the fit kept (joints in each camera's frame, mm; the turn error: the "
        "direction the pelvis and the chest face about the camera's vertical against the truth's, less its median over "
        "the frames, which Procrustes alignment hides).", "",
        "| subject | kept / read | MPJPE | PA-MPJPE | PA arms | PA legs | PA head | turn error, pelvis / chest: median (p90), deg | "
        "mask IoU (person) | body vs person mask | reprojection px | focal px (true) | s per 300 frames |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in r["rows"]:
        lines.append(f"| {row['subject']} | {row['frames_kept']} / {row['frames_read']} | {row['mpjpe']} | {row['pa_mpjpe']} | "
                     f"{row['pa_arms']} | {row['pa_legs']} | {row['pa_head']} | {row['pelvis_turn_deg']} ({row['pelvis_turn_p90_deg']}) / "
                     f"{row['chest_turn_deg']} ({row['chest_turn_p90_deg']}) | {row['mask_iou']} | {row['body_mask_iou']} | "
                     f"{row['reprojection_px']} | {row['focal_px']} ({row['true_focal_px']}) | {row['seconds_per_300_frames']} |")
    t = r["targets"]
    worst_pa = max(row["pa_mpjpe"] for row in r["rows"])
    worst_s = max(row["seconds_per_300_frames"] for row in r["rows"])
    lines += ["", f"Targets: PA-MPJPE <= {t['pa_mpjpe_mm']} mm: {'met' if worst_pa <= t['pa_mpjpe_mm'] else 'MISSED'} "
              f"(worst {worst_pa}); 300 frames <= {t['seconds_per_300_frames']:.0f} s: "
              f"{'met' if worst_s <= t['seconds_per_300_frames'] else 'MISSED'} (worst {worst_s}); peak RSS "
              f"{r['peak_rss_mib']} MiB (<= {t['peak_rss_mib']:.0f}: {'met' if r['peak_rss_mib'] <= t['peak_rss_mib'] else 'MISSED'}).",
              "", "Dropped frames per subject: " + "; ".join(f"{row['subject']}: {row['dropped'] or 'none'}" for row in r["rows"]), ""]
    if "cost_of_fitting_db" in r["rows"][0]:
        lines += [f"The cost of fitting (`--avatar-iterations {c['avatar_iterations']}`: the same avatar trained on the fitted subject, "
                  "on it with `--refine-poses`, on its twin with the true poses, cameras and masks, same frames and split, and on the "
                  "twin with the true poses and cameras on the fitted subject's own frames and masks (what the video's "
                  "frames and the person model's masks cost apart from the poses); "
                  "masked test PSNR on the held-out video frames; target: within 1.0 dB):", "",
                  "| subject | fitted poses | fitted, refined | true poses | true poses, the video's frames and masks | "
                  "cost (dB) | cost refined (dB) | of which the frames (dB) |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {row['subject']} | {row['psnr_fitted_poses']} | {row['psnr_refined_poses']} | {row['psnr_true_poses']} | "
                  f"{row['psnr_true_poses_video_frames']} | {row['cost_of_fitting_db']} | {row['cost_refined_db']} | "
                  f"{row['cost_of_the_frames_db']} |" for row in r["rows"]]
        lines += ["", "The same runs at test poses refitted to each held-out frame's pixels with the avatar frozen "
                  "(`trioman eval --poses optimised`: test-time pose optimisation, as avatar papers evaluate on fitted "
                  "captures; the true-pose twins refitted the same way):", "",
                  "| subject | fitted poses | fitted, refined | true poses | true poses, the video's frames and masks | "
                  "cost (dB) | cost refined (dB) | cost against the same frames (dB) | cost refined, same frames (dB) |",
                  "|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {row['subject']} | {row['psnr_fitted_refitted']} | {row['psnr_refined_refitted']} | "
                  f"{row['psnr_true_refitted']} | {row['psnr_true_video_refitted']} | {row['cost_fitted_refitted_db']} | "
                  f"{row['cost_refined_refitted_db']} | {row['cost_fitted_refitted_same_frames_db']} | "
                  f"{row['cost_refined_refitted_same_frames_db']} |" for row in r["rows"]]
        worst = max(max(row[f"cost_{arm}_refitted{vs}_db"] for arm in ("fitted", "refined") for vs in ("", "_same_frames"))
                    for row in r["rows"])
        lines += ["", f"Target, the avatar on fitted poses within {t['cost_of_fitting_db']} dB of the one on true poses "
                  f"(refitted, every column): {'met' if worst <= t['cost_of_fitting_db'] else 'MISSED'} (worst {worst}).", ""]
    return "\n".join(lines)
