"""``trioman augment``: Generator -> coarse render -> normal map -> Refiner -> Examiner, end to end on a tiny
subject and avatar, the shipped Examiner and Refiner and small Refiner ONNX files (tests.runtime.augment_inputs, built
without torch); records, summary, threshold, determinism, resume after an interruption, refusals and bad inputs; a
run without torch."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import trioman.runtime.augment.step as augment_step  # the per-frame step, whose write_png is patched
from tests.conftest import run_python
from tests.runtime.augment_runs import LIMIT, run, snapshot
from trioman.cli import main
from trioman.runtime.augment import AUGMENT_JSON, HISTOGRAM_PNG, STAGES, augment, frame_seed
from trioman.runtime.aligned import Aligner, SourceViews
from trioman.runtime.formats import FormatError, load_avatar, load_subject
from trioman.runtime.formats.avatar import sha256_file
from trioman.runtime.generator import GROUPS, sample
from trioman.runtime.image_io import png_header, read_png, to_uint8
from trioman.runtime.onnx_models import ExaminerModel, RefinerModel
from trioman.runtime.normal_map import body_normal_map
from trioman.runtime.render import rasterize


def records(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "records").glob("*.json"))]


# --------------------------------------------------------------------------------------------------


def test_with_an_examiner_the_better_candidate_becomes_a_pseudo_gt_frame(inputs, straight):
    out, src = straight.out, load_subject(inputs.subject)
    aug = load_subject(out)
    recs = records(out)
    assert len(recs) == aug.num_frames == LIMIT
    assert set(aug.split.tolist()) == {"train"} and (aug.width, aug.height) == (src.width, src.height)
    assert (out / "body.npz").read_bytes() == (inputs.subject / "body.npz").read_bytes()
    assert aug.meta["background"] == src.meta["background"] and aug.meta["generator"]["tool"] == "trioman augment"
    for k, rec in enumerate(recs):
        i = rec["source"]["index"]
        scores = [c["score"] for c in rec["candidates"]]
        assert len(scores) == 2 and rec["chosen"] == int(np.argmax(scores)) and rec["kept"]
        assert [c["status"] for c in rec["candidates"]] == ["accepted" if j == rec["chosen"] else "not_chosen" for j in range(2)]
        assert aug.frame_names[k] == f"{src.frame_names[i]}_c{rec['chosen']}" and aug.sequence[k] == src.sequence[i]
        assert rec["seed"] == frame_seed(7, i)
        for f in rec["frames"]:  # each written file's sha256 (check_record verifies them at --merge)
            assert f["sha256"] == {d: hashlib.sha256((out / d / f"{f['name']}.png").read_bytes()).hexdigest()
                                   for d in ("images", "masks")}
        for c in rec["candidates"]:
            assert set(c["camera"]) == {"azimuth", "elevation", "log_distance"}
            assert set(c["pose_delta_norm"]) <= set(GROUPS) and c["pose_delta_norm"]["root"] == 0.0
        np.testing.assert_array_equal(aug.K[k], src.K[i])

    # Frame 0 again by hand: the candidate from the recorded seed, the carried silhouette as the mask (the body
    # mesh and the source mask carried to the draw), the Refiner fed the real frame and the normal map, the
    # Examiner's scores against the real frame.
    rec, i = recs[0], recs[0]["source"]["index"]
    av = load_avatar(inputs.avatar)
    cands = sample(src.body.skeleton, src.poses[i], src.trans[i], src.viewmat[i], rec["seed"], 2)
    c = cands[rec["chosen"]]
    np.testing.assert_array_equal(aug.poses[0], c.pose.astype(np.float32))
    np.testing.assert_array_equal(aug.viewmat[0], c.viewmat.astype(np.float32))
    K, W, H = np.array(src.K[i], np.float64), src.width, src.height
    renders = [rasterize(*av.gaussians(x.pose, x.trans), x.viewmat, K, W, H, background=src.background) for x in cands]
    every = src.indices(None)  # --frames all: real pixels are carried from every frame
    views = SourceViews(lambda p: src.image(int(every[p])) * src.mask(int(every[p]))[..., None], lambda p: src.mask(int(every[p])),
                        src.poses[every], src.trans[every], src.viewmat[every], src.K[every], W, H)
    silhouette = Aligner(src.body, views).align(int(np.flatnonzero(every == i)[0]), c.pose, c.trans, c.viewmat, K).silhouette
    assert silhouette.max() == 1.0 and 0 < silhouette.mean() < 0.9
    np.testing.assert_array_equal(to_uint8(read_png(aug.mask_path(0))), to_uint8(silhouette))
    real = src.image(i)
    normals = np.stack([body_normal_map(src.body, x.pose, x.trans, x.viewmat, K, W, H).rgb for x in cands])
    refined = RefinerModel(inputs.refiner).refine(np.stack([np.clip(r.rgb, 0, 1) for r in renders]),
                                                   np.stack([real, real]), normals)
    a = silhouette[..., None]  # the refined frame through the mask
    np.testing.assert_array_equal(to_uint8(read_png(aug.image_path(0))),
                                  to_uint8(refined[rec["chosen"]] * a + (1 - a) * src.background))
    np.testing.assert_allclose([c["score"] for c in rec["candidates"]], ExaminerModel(inputs.examiner).score(refined, real),
                               atol=1e-6)

    meta = json.loads((out / AUGMENT_JSON).read_text())
    s, st = meta["summary"], meta["settings"]
    assert meta["status"] == "complete" and meta["versions"]["trioman"]
    counts = (s["source_frames"], s["candidates"], s["accepted"], s["rejected"], s["not_chosen"])
    assert counts == (LIMIT, 2 * LIMIT, LIMIT, 0, LIMIT)
    all_scores = [c["score"] for r in recs for c in r["candidates"]]
    assert s["scores"]["count"] == 2 * LIMIT and s["scores"]["max"] == max(all_scores) and s["scores"]["min"] == min(all_scores)
    assert s["subject_written"] and s["histogram"] == HISTOGRAM_PNG and png_header(out / HISTOGRAM_PNG) == (640, 400, 3)
    assert st["avatar"]["step"] == 3 and st["avatar"]["avatar_json_sha256"] == sha256_file(inputs.avatar / "avatar.json")
    ref_meta = RefinerModel(inputs.refiner).meta
    assert st["refiner"]["config_hash"] == ref_meta["trioman.config_hash"] and st["refiner"]["precision"] == "fp32"
    assert st["examiner"]["sha256"] == sha256_file(inputs.examiner)
    assert (st["seed"], st["per_frame"], st["threshold"], st["frames"], st["mask"]) == (7, 2, None, "all", "carried")
    assert set(meta["timing"]["ms_per_source_frame"]) == set(STAGES) | {"total"}
    assert all(v >= 0 for v in meta["timing"]["ms_per_source_frame"].values())


def test_threshold_rejects_low_scores_and_can_reject_everything(inputs, straight, tmp_path, capsys):
    chosen = sorted(r["candidates"][r["chosen"]]["score"] for r in records(straight.out))
    thr = 0.5 * (chosen[1] + chosen[2])  # two above, two below
    run(inputs, tmp_path / "t", threshold=thr)
    recs = records(tmp_path / "t")
    assert [r["kept"] for r in recs] == [r["candidates"][r["chosen"]]["score"] >= thr for r in recs]
    assert sum(r["kept"] for r in recs) == 2 and load_subject(tmp_path / "t").num_frames == 2
    assert {c["status"] for r in recs for c in r["candidates"]} == {"accepted", "rejected", "not_chosen"}
    s = json.loads((tmp_path / "t" / AUGMENT_JSON).read_text())["summary"]
    assert (s["accepted"], s["rejected"]) == (2, 2)

    assert max(c["score"] for r in recs for c in r["candidates"]) < 1.0
    out = tmp_path / "none"
    assert main(["augment", str(inputs.subject), "--avatar", str(inputs.avatar), "--refiner", str(inputs.refiner),
                 "--examiner", str(inputs.examiner), "--out", str(out), "--threshold", "1", "--frames", "all",
                 "--limit", "2", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "0 accepted, 2 rejected (threshold 1)" in printed and "no pseudo-GT subject written" in printed
    assert str(out / AUGMENT_JSON) in printed and str(out / HISTOGRAM_PNG) in printed
    s = json.loads((out / AUGMENT_JSON).read_text())["summary"]
    assert (s["accepted"], s["rejected"], s["subject_written"]) == (0, 2, False) and "0 accepted" in s["note"]
    assert not (out / "subject.json").exists() and not (out / "frames.npz").exists() and (out / HISTOGRAM_PNG).is_file()
    assert not list((out / "images").iterdir()) and len(records(out)) == 2
    with pytest.raises(FormatError, match="subject.json"):
        load_subject(out)


def test_without_an_examiner_every_candidate_is_kept(inputs, tmp_path):
    out = tmp_path / "all"
    r = run(inputs, out, examiner=False, per_frame=3, limit=2)
    aug = load_subject(out)
    names = [str(n) for n in load_subject(inputs.subject).frame_names[:2]]
    assert aug.frame_names.tolist() == [f"{n}_c{k}" for n in names for k in range(3)]
    assert r["summary"]["accepted"] == 6 and r["summary"]["histogram"] is None and not (out / HISTOGRAM_PNG).exists()
    assert r["settings"]["examiner"] is None and r["summary"]["scores"]["count"] == 0
    assert {c["status"] for rec in records(out) for c in rec["candidates"]} == {"kept"}
    assert all(c["score"] is None for rec in records(out) for c in rec["candidates"])


def test_a_refiner_without_conditions_gets_neither_reference_nor_normal_map(inputs, tmp_path):
    r = augment(inputs.subject, inputs.avatar, inputs.refiner_none, tmp_path / "n", None, limit=1, progress=False)
    assert r["settings"]["refiner"]["conditions"] == "none" and r["timing"]["ms_per_source_frame"]["normal"] < 1.0
    assert load_subject(tmp_path / "n").num_frames == 2


def test_a_refiner_exported_at_another_size_refines_the_subjects(inputs, tmp_path):
    """Exported at 16x16, it takes the subject's 32x32 frames: the frames of the same weights exported at 32x32."""
    r = augment(inputs.subject, inputs.avatar, inputs.refiner16, tmp_path / "a", None, limit=1, progress=False)
    assert r["settings"]["refiner"]["size"] == [16, 16] and RefinerModel(inputs.refiner16).multiple == 4
    augment(inputs.subject, inputs.avatar, inputs.refiner, tmp_path / "b", None, limit=1, progress=False)
    a, b = load_subject(tmp_path / "a"), load_subject(tmp_path / "b")
    assert a.num_frames == b.num_frames == 2
    for i in range(2):
        np.testing.assert_allclose(a.image(i), b.image(i), atol=1.5 / 255)  # one 8-bit step at most


def test_a_warp_refiner_refines_the_aligned_reference(inputs, tmp_path):
    """A warp+geo Refiner ONNX in the runtime: the aligned reference is built for it (even with the render's alpha as
    the mask), and its frames differ from the same draws refined by a tex+geo Refiner."""
    r = augment(inputs.subject, inputs.avatar, inputs.refiner_warp, tmp_path / "w", None, limit=1, progress=False, mask="alpha")
    assert r["settings"]["refiner"]["conditions"] == "warp+geo" and r["timing"]["ms_per_source_frame"]["align"] > 0
    assert all(0 < c["body_coverage"] <= 1 for rec in records(tmp_path / "w") for c in rec["candidates"])
    augment(inputs.subject, inputs.avatar, inputs.refiner, tmp_path / "t", None, limit=1, progress=False, mask="alpha")
    warp, tex = load_subject(tmp_path / "w"), load_subject(tmp_path / "t")
    assert warp.num_frames == tex.num_frames == 2 and not np.array_equal(warp.image(0), tex.image(0))


def test_same_seed_same_files_and_resume_after_an_interruption(inputs, straight, tmp_path, monkeypatch):
    run(inputs, tmp_path / "again")
    assert snapshot(tmp_path / "again") == straight.files
    run(inputs, tmp_path / "seed8", seed=8, limit=1)
    assert (tmp_path / "seed8" / "frames.npz").read_bytes() != (tmp_path / "again" / "frames.npz").read_bytes()

    # Interrupt while writing the third frame: its image is written, its mask and record are not.
    calls = []
    real_write = augment_step.write_png

    def flaky(path, img):
        calls.append(path)
        if len(calls) == 6:
            raise KeyboardInterrupt
        real_write(path, img)

    monkeypatch.setattr(augment_step, "write_png", flaky)
    out = tmp_path / "broken"
    with pytest.raises(KeyboardInterrupt):
        run(inputs, out)
    monkeypatch.setattr(augment_step, "write_png", real_write)
    assert len(records(out)) == 2 and len(list((out / "images").iterdir())) == 3 and len(list((out / "masks").iterdir())) == 2
    assert not (out / "subject.json").exists()
    with pytest.raises(FormatError):
        load_subject(out)
    r = run(inputs, out, resume=True)
    assert r["timing"]["frames_resumed"] == 2 and r["timing"]["frames_computed"] == LIMIT - 2
    assert snapshot(out) == straight.files  # byte-identical images, masks, frames.npz, subject.json, histogram
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
    r = run(inputs, out, resume=True)  # a finished run resumes to the same files
    assert r["timing"]["frames_resumed"] == LIMIT and snapshot(out) == straight.files


def test_refuses_a_non_empty_out_and_a_resume_with_other_settings(inputs, tmp_path):
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match=r"^out: .* not empty \(pass `resume` .* `overwrite`"):
        run(inputs, stray, limit=1)
    for flag in ("resume", "overwrite"):
        with pytest.raises(FileExistsError, match="holds no augment.json"):
            run(inputs, stray, limit=1, **{flag: True})
    assert (stray / "notes.txt").read_text() == "mine" and len(list(stray.iterdir())) == 1

    out = tmp_path / "done"
    run(inputs, out, limit=1)
    with pytest.raises(FileExistsError, match="not empty"):
        run(inputs, out, limit=1)
    with pytest.raises(ValueError, match=r"^resume: seed differs from the run in .* \(was 7, now 9\)"):
        run(inputs, out, limit=1, seed=9, resume=True)
    with pytest.raises(ValueError, match="^resume: per_frame differs"):
        run(inputs, out, limit=1, per_frame=3, resume=True)
    r = run(inputs, out, limit=1, seed=9, overwrite=True, examiner=False)
    assert r["settings"]["seed"] == 9 and load_subject(out).num_frames == 2 and not (out / HISTOGRAM_PNG).exists()


def test_overwrite_removes_only_what_augment_wrote_and_resume_removes_temporary_files(inputs, tmp_path):
    # issue 18, cases 4 and 11
    out = tmp_path / "o"
    run(inputs, out, limit=1)
    temps = [out / "masks" / ".000000_c0.png.0123abcd.tmp.png", out / ".frames.npz.deadbeef.tmp.npz"]
    for p in temps:  # what a kill -9 leaves behind
        p.write_bytes(b"partial")
    run(inputs, out, limit=2, resume=True)
    assert not any(p.exists() for p in temps)
    for foreign in (out / "notes.txt", out / "images" / "mine.png", out / "records" / "notes.txt"):
        foreign.write_text("not augment's")
        before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
        with pytest.raises(FileExistsError, match=rf"^overwrite: {foreign} was not written by trioman augment"):
            run(inputs, out, limit=1, overwrite=True)
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # nothing removed
        foreign.unlink()
    (out / "images" / "000003_c1.png").write_bytes(b"an interrupted frame's image, no record yet")
    temps[0].write_bytes(b"partial")
    run(inputs, out, limit=1, overwrite=True)
    assert len(records(out)) == 1 and not (out / "images" / "000003_c1.png").exists() and not temps[0].exists()


@pytest.mark.parametrize("args, message", [
    (["--per-frame", "0"], "--per-frame: must be an integer in [1, 64], got 0"),
    (["--per-frame", "100000000"], "--per-frame: must be an integer in [1, 64], got 100000000"),  # issue 41, D12
    (["--threshold", "1.5"], "--threshold: must be a number in [0, 1], got 1.5"),
    (["--threshold", "-0.1"], "--threshold: must be a number in [0, 1], got -0.1"),
    (["--limit", "0"], "--limit: must be an integer >= 1, got 0"),
    (["--seed", "-1"], "--seed: must be an integer >= 0, got -1"),
    (["--resume", "--overwrite"], "--resume and --overwrite: choose one"),
    (["--refiner", "{root}/missing.onnx"], "--refiner: Refiner ONNX file not found: {root}/missing.onnx"),
    (["--examiner", "{root}/missing.onnx"], "--examiner: Examiner ONNX file not found: {root}/missing.onnx"),
    (["--refiner", "{root}/refiner16_fixed.onnx"], "refiner16_fixed.onnx takes 16x16 (H x W) images only, but the subject's "
                                                   "images are 32x32; export the Refiner again (trioman export onnx --refiner "
                                                   "CKPT): an export with `trioman.size_multiple` takes any size"),
    (["--refiner", "{root}/examiner.onnx"], "metadata 'trioman.kind': expected 'refiner', got 'examiner'"),
    (["--avatar", "{root}/other_avatar"], "other_avatar has 5 joints, but the subject's body has 18 joints"),
], ids=["per-frame", "per-frame-huge", "threshold-high", "threshold-low", "limit", "seed", "resume-overwrite", "refiner-missing",
        "examiner-missing", "refiner-size", "refiner-kind", "joints"])
def test_bad_inputs_fail_before_any_work(inputs, tmp_path, capsys, args, message):
    out = tmp_path / "out"
    base = {"--avatar": str(inputs.avatar), "--refiner": str(inputs.refiner), "--examiner": str(inputs.examiner),
            "--out": str(out)}
    args = [a.replace("{root}", str(inputs.root)) for a in args]
    for flag in list(base):
        if flag in args:
            base[flag] = args.pop(args.index(flag) + 1)
            args.remove(flag)
    argv = ["augment", str(inputs.subject), "--quiet"] + [x for kv in base.items() for x in kv] + args
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert message.replace("{root}", str(inputs.root)) in err, err
    assert not out.exists()


def test_a_full_disk_is_one_line_naming_the_file_and_the_run_resumes(inputs, straight, tmp_path, capsys, monkeypatch):
    # issue 18, case 2: the disk fills while the third frame's image is written
    from tests.full_disk import full_disk_open
    from trioman.runtime import outputs

    out = tmp_path / "full"
    writes = []

    def filling(path, mode="r", *args, **kw):
        if "w" in mode:
            writes.append(path)
        return full_disk_open(path, mode, *args, **kw) if len(writes) > 7 else open(path, mode, *args, **kw)

    monkeypatch.setattr(outputs, "open", filling, raising=False)
    argv = ["augment", str(inputs.subject), "--avatar", str(inputs.avatar), "--refiner", str(inputs.refiner),
            "--examiner", str(inputs.examiner), "--out", str(out), "--frames", "all", "--limit", str(LIMIT),
            "--seed", "7", "--no-keep-carried", "--quiet"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    third = records(straight.out)[2]["frames"][0]["name"]  # the third frame's image, as the run without a full disk wrote it
    assert f"{out / 'images' / third}.png: no space left on the device" in err, err
    assert not [p for p in out.rglob("*") if outputs.is_temp_name(p.name)]  # no partial file
    monkeypatch.undo()
    assert main(argv + ["--resume"]) == 0  # the finished frames stay; the run completes
    assert snapshot(out) == straight.files


def test_threshold_without_an_examiner_is_refused(inputs, tmp_path):
    with pytest.raises(ValueError, match=r"^threshold: 0.5 needs an Examiner \(`examiner`\)"):
        run(inputs, tmp_path / "o", examiner=False, threshold=0.5)
    assert not (tmp_path / "o").exists()


def test_augment_runs_without_torch(inputs, tmp_path):
    out = tmp_path / "notorch"
    proc = run_python(f"""
        import sys
        from trioman.cli import main
        assert main(['augment', {str(inputs.subject)!r}, '--avatar', {str(inputs.avatar)!r},
                     '--refiner', {str(inputs.refiner)!r}, '--examiner', {str(inputs.examiner)!r},
                     '--out', {str(out)!r}, '--limit', '1', '--quiet']) == 0
        for name in ('torch', 'onnx', 'matplotlib'):
            assert sys.modules.get(name) is None, name
    """, block_torch=True)
    assert proc.returncode == 0, proc.stderr
    assert "1 accepted, 0 rejected" in proc.stdout and "ms per source frame" in proc.stdout
    assert load_subject(out).num_frames == 1


def test_mask_alpha_keeps_the_render_alpha(inputs, tmp_path):
    """--mask alpha (the paper's): the pseudo frame's mask is the avatar render's own alpha at the draw."""
    out = tmp_path / "alpha"
    run(inputs, out, examiner=False, limit=1, mask="alpha")
    src, aug, rec = load_subject(inputs.subject), load_subject(out), records(out)[0]
    i = rec["source"]["index"]
    c = sample(src.body.skeleton, src.poses[i], src.trans[i], src.viewmat[i], rec["seed"], 2)[0]
    r = rasterize(*load_avatar(inputs.avatar).gaussians(c.pose, c.trans), c.viewmat, np.array(src.K[i], np.float64),
                  src.width, src.height, background=src.background)
    np.testing.assert_array_equal(to_uint8(read_png(aug.mask_path(0))), to_uint8(np.clip(r.alpha, 0, 1)))
    assert aug.meta["generator"]["mask"] == "avatar render alpha"
    with pytest.raises(ValueError, match="^mask: expected one of"):
        run(inputs, tmp_path / "bad", mask="silhouette")


def test_without_a_refiner_the_frames_are_aligned_with_per_pixel_weights(inputs, tmp_path):
    """No model: the render with real pixels carried through the body mesh; weights 0 on body pixels no real pixel
    reached, 1 elsewhere, written to weights/ beside the masks (and resumed like the rest)."""
    out = tmp_path / "aligned"
    augment(inputs.subject, inputs.avatar, None, out, frames="all", limit=2, seed=7, progress=False, per_frame=1)
    aug, recs = load_subject(out), records(out)
    assert aug.num_frames == 2 and aug.meta["generator"]["kind"] == "aligned"
    assert json.loads((out / AUGMENT_JSON).read_text())["settings"]["refiner"] is None
    for rec in recs:
        f = rec["frames"][0]
        assert f["weights"] is True and 0 <= rec["candidates"][0]["body_coverage"] <= 1
        w = read_png(out / "weights" / f"{f['name']}.png", mode="gray")
        assert w.shape == (aug.height, aug.width) and set(np.unique(w)) <= {0.0, 1.0}
        assert (w == 1).mean() > 0.5
    before = snapshot(out)
    (out / "records" / f"{recs[1]['source']['name']}.json").unlink()  # interrupted before its record
    augment(inputs.subject, inputs.avatar, None, out, frames="all", limit=2, seed=7, progress=False, per_frame=1,
            resume=True)
    assert snapshot(out) == before
    with pytest.raises(ValueError, match="^examiner: chooses among refined candidates; give `refiner` too"):
        augment(inputs.subject, inputs.avatar, None, tmp_path / "e", inputs.examiner, progress=False)


def test_a_fused_texture_colours_the_aligned_frames_and_is_recorded(inputs, tmp_path):
    """--texture N: the aligned reference's colour from the texture fused from every source frame (where seen);
    recorded in the settings (a resume with another value is refused); a bad value is refused before any work."""
    plain, fused = tmp_path / "plain", tmp_path / "fused"
    for out, texture in ((plain, 0), (fused, 32)):
        augment(inputs.subject, inputs.avatar, None, out, frames="all", limit=1, seed=7, progress=False, per_frame=1,
                texture=texture)
    settings = json.loads((fused / AUGMENT_JSON).read_text())["settings"]
    assert settings["texture"] == 32 and "texture" not in json.loads((plain / AUGMENT_JSON).read_text())["settings"]
    a, b = load_subject(plain), load_subject(fused)
    assert not np.array_equal(a.image(0), b.image(0)) and np.array_equal(a.mask(0), b.mask(0))
    rec = records(fused)[0]
    assert rec["candidates"][0]["body_coverage"] >= records(plain)[0]["candidates"][0]["body_coverage"]
    with pytest.raises(ValueError, match="^texture: 0 .* got 8"):
        augment(inputs.subject, inputs.avatar, None, tmp_path / "bad", texture=8, progress=False)
    assert not (tmp_path / "bad").exists()


def test_keep_carried_keeps_the_carried_pixels_and_refines_only_the_rest(inputs, tmp_path, capsys):
    """--keep-carried (the default with --refiner): where a real pixel was carried to the draw the pseudo-GT shows
    it, elsewhere the Refiner's output, the same bytes as with --no-keep-carried; recorded in the settings and the
    subject; refused without --refiner; a resume with the other value is refused, and a run that did not record it
    resumes as one without it."""
    base = ["augment", str(inputs.subject), "--avatar", str(inputs.avatar), "--refiner", str(inputs.refiner),
            "--examiner", "none", "--frames", "all", "--limit", "1", "--seed", "7", "--quiet"]
    plain, kept = tmp_path / "plain", tmp_path / "kept"
    assert main(base + ["--out", str(plain), "--no-keep-carried"]) == 0
    assert main(base + ["--out", str(kept)]) == 0
    capsys.readouterr()
    a, b = load_subject(plain), load_subject(kept)
    assert a.frame_names.tolist() == b.frame_names.tolist() and b.num_frames == 2  # no Examiner: both candidates
    assert json.loads((kept / AUGMENT_JSON).read_text())["settings"]["keep_carried"] is True
    assert json.loads((plain / AUGMENT_JSON).read_text())["settings"]["keep_carried"] is False
    assert b.meta["generator"]["keep_carried"] is True and a.meta["generator"]["keep_carried"] is False

    src, av, rec = load_subject(inputs.subject), load_avatar(inputs.avatar), records(kept)[0]
    every, i = src.indices(None), rec["source"]["index"]  # --frames all: real pixels are carried from every frame
    K, W, H, bg = np.array(src.K[i], np.float64), src.width, src.height, src.background.astype(np.float32)
    aligner = Aligner(src.body, SourceViews.of_subject(src, every))
    for k, c in enumerate(sample(src.body.skeleton, src.poses[i], src.trans[i], src.viewmat[i], rec["seed"], 2)):
        coarse = np.clip(rasterize(*av.gaussians(c.pose, c.trans), c.viewmat, K, W, H, background=bg).rgb, 0.0, 1.0)
        al = aligner.align(int(np.flatnonzero(every == i)[0]), c.pose, c.trans, c.viewmat, K, coarse)
        assert 0 < al.valid.mean() < 1
        np.testing.assert_array_equal(read_png(a.mask_path(k)), read_png(b.mask_path(k)))  # the same carried mask
        plain_img, kept_img = to_uint8(read_png(a.image_path(k))), to_uint8(read_png(b.image_path(k)))
        np.testing.assert_array_equal(kept_img[~al.valid], plain_img[~al.valid])  # nothing carried: the Refiner's
        m = al.silhouette[..., None]
        np.testing.assert_array_equal(kept_img[al.valid], to_uint8(al.rgb * m + (1.0 - m) * bg)[al.valid])  # the real
        assert (kept_img[al.valid] != plain_img[al.valid]).any()

    no = tmp_path / "no"
    assert main(["augment", str(inputs.subject), "--avatar", str(inputs.avatar), "--out", str(no), "--refiner", "none",
                 "--keep-carried", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "--keep-carried: takes the Refiner's output where nothing was carried; give --refiner too" in err, err
    assert not no.exists()
    with pytest.raises(ValueError, match="^keep_carried: takes the Refiner's output .* give `refiner` too"):
        augment(inputs.subject, inputs.avatar, None, no, keep_carried=True, progress=False)
    with pytest.raises(ValueError, match="^keep_carried: must be true, false or None .*, got 1"):
        augment(inputs.subject, inputs.avatar, inputs.refiner, no, keep_carried=1, progress=False)
    assert not no.exists()

    assert main(base + ["--out", str(plain), "--resume"]) == 1  # the default keeps them
    err = capsys.readouterr().err
    assert f"--resume: keep_carried differs from the run in {plain} (was False, now True); use the same inputs, or " \
           f"--overwrite to start again" in err, err
    meta = json.loads((plain / AUGMENT_JSON).read_text())
    del meta["settings"]["keep_carried"]  # a run of a version that did not record it
    (plain / AUGMENT_JSON).write_text(json.dumps(meta))
    assert main(base + ["--out", str(plain), "--resume", "--no-keep-carried"]) == 0
    assert json.loads((plain / AUGMENT_JSON).read_text())["timing"]["frames_resumed"] == 1


def test_the_output_never_is_holds_or_enters_an_input(inputs, tmp_path, capsys):
    # issue 41, D1 and D6: `augment AUG --out AUG --overwrite` deleted its input; --out SUBJECT/aug was accepted
    out = tmp_path / "aug"
    run(inputs, out, limit=1)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    argv = ["augment", str(out), "--avatar", str(inputs.avatar), "--refiner", str(inputs.refiner), "--quiet"]
    assert main(argv + ["--out", str(out), "--overwrite"]) == 1
    assert f"--out: {out}: is the input {out}; write the output to another folder" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    for inside in (out / "again", inputs.avatar / "aug"):
        assert main(argv + ["--out", str(inside)]) == 1
        assert "lies inside the input" in capsys.readouterr().err and not inside.exists()


def test_a_link_inside_an_earlier_output_is_refused_before_anything_is_written(inputs, tmp_path):
    # issue 41, D4: `augment --overwrite` where OUT/images links to a folder outside replaced files there
    out, outside = tmp_path / "o", tmp_path / "outside"
    run(inputs, out, limit=1)
    shutil.move(out / "images", outside)
    (out / "images").symlink_to(outside, target_is_directory=True)
    before = {p: p.read_bytes() for p in outside.iterdir()}
    for flag in ("overwrite", "resume"):
        with pytest.raises(FileExistsError, match=rf"^out: {out / 'images'} is a link, which trioman augment never writes"):
            run(inputs, out, limit=2, **{flag: True})
    assert {p: p.read_bytes() for p in outside.iterdir()} == before and (out / "images").is_symlink()


def test_a_second_run_into_the_same_output_is_refused_while_the_first_writes(inputs, tmp_path):
    # issue 41, D5: two unsharded runs into one --out both exited 0, one result silently replaced
    import os

    from trioman.runtime.outputs import process_lock

    out = tmp_path / "busy"
    lock = tmp_path / ".busy.augment.lock"
    with process_lock(lock, "the first run"):  # held as the first run holds it
        with pytest.raises(ValueError, match=rf"^out: another `augment` run into {out} is running \(pid {os.getpid()}"):
            run(inputs, out, overwrite=True)
        assert not out.exists()  # nothing written
    lock.write_text('{"pid": 1}')  # what a killed run leaves: a file nobody holds, which is no obstacle
    run(inputs, out)
    assert not lock.exists()  # released when the run ends


def test_a_run_that_fails_says_so_in_augment_json(inputs, tmp_path, monkeypatch):
    # issue 41, U4: a run stopped by an error left augment.json "running"
    def broken(*args, **kw):
        raise RuntimeError("the Refiner's session died")

    monkeypatch.setattr("trioman.runtime.augment.run.augment_frame", broken)
    with pytest.raises(RuntimeError):
        run(inputs, tmp_path / "o")
    record = json.loads((tmp_path / "o" / AUGMENT_JSON).read_text())
    assert (record["status"], record["error"]) == ("failed", "RuntimeError: the Refiner's session died")
    assert not (tmp_path / ".o.augment.lock").exists()
