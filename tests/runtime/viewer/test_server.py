"""``trioman view``'s server: it serves the client page on a free port, one pose update sends the splat
arrays that changed (right shapes, right bytes), it shuts down cleanly, and bad inputs (avatar folders,
a busy port) are one-line errors. Without viser these tests skip."""

import socket
import time
from pathlib import Path
import urllib.request

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer needs viser: pip install 'trioman[viewer]'")

from tests.conftest import run_python  # noqa: E402
from tests.runtime.factories import edit_json  # noqa: E402
from tests.runtime.viewer.helpers import N_GAUSSIANS, make_augment_output, make_avatar, make_subject  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.runtime.viewer.app import open_viewer  # noqa: E402
from trioman.runtime.viewer.server import SPLATS  # noqa: E402


@pytest.fixture
def avatar_dir(tmp_path):
    make_avatar(tmp_path / "avatar")
    return tmp_path / "avatar"


@pytest.fixture
def viewer(avatar_dir):
    v = open_viewer(avatar_dir, port=0)
    yield v
    v.stop()


def free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_serves_the_client_page_on_a_free_port(viewer):
    assert viewer.url.startswith("http://127.0.0.1:") and viewer.server.get_port() > 0
    with urllib.request.urlopen(viewer.url, timeout=10) as r:
        page = r.read().decode("utf-8", "replace")
    assert r.status == 200 and "<html" in page.lower() and "<script" in page.lower()
    assert viewer.poser.name == "rest"  # no shipped motion fits the 3-joint chain
    assert viewer.poser.bend_groups == ("root", "other")


def decode(buffer: np.ndarray) -> dict[str, np.ndarray]:
    """viser's splat buffer [N, 8] uint32 -> centres, covariance upper triangle, RGBA."""
    return {"centers": buffer[:, 0:3].copy().view(np.float32), "cov": buffer[:, 4:7].copy().view(np.float16),
            "rgba": buffer[:, 7:8].copy().view(np.uint8).reshape(-1, 4)}


def test_one_pose_update_sends_the_changed_arrays(viewer, monkeypatch):
    sent = []
    scene = viewer.server.scene
    queue = scene._queue_scene_message
    monkeypatch.setattr(scene, "_queue_scene_message", lambda m: (sent.append(m), queue(m)))
    viewer.controls.bends = {"other": 60.0}
    changed = viewer.refresh()
    # isotropic, no pose-dependent terms: a bend moves the centres only
    assert {k: v.shape for k, v in changed.items()} == {"centers": (N_GAUSSIANS, 3)}
    assert viewer.last_update["arrays"] == {"centers": (N_GAUSSIANS, 3)}
    updates = [m for m in sent if getattr(m, "name", None) == SPLATS and "buffer" in getattr(m, "updates", {})]
    assert len(updates) == 1
    buf = decode(updates[0].updates["buffer"])
    assert updates[0].updates["buffer"].shape == (N_GAUSSIANS, 8)
    g = viewer.poser.gaussians(viewer.controls)
    np.testing.assert_array_equal(buf["centers"], g.means)
    np.testing.assert_allclose(buf["cov"][:, [0, 3, 5]].astype(np.float32), np.square(g.scales), rtol=1e-3)
    np.testing.assert_array_equal(buf["cov"][:, [1, 2, 4]], 0)
    np.testing.assert_array_equal(buf["rgba"][:, :3], np.round(g.colors * 255).astype(np.uint8))
    np.testing.assert_array_equal(buf["rgba"][:, 3], round(0.9 * 255))
    top = g.means[:, 2] > 1.3
    assert np.abs(g.means[top, 1]).max() > 0.1  # the upper joints bent forward (about x)
    sent.clear()
    assert viewer.refresh() == {} and sent == []  # nothing changed, nothing sent


def test_clean_shutdown(avatar_dir):
    v = open_viewer(avatar_dir, port=0)
    port = v.server.get_port()
    v.playing = True
    v.stop()
    v.stop()  # idempotent
    assert not v._worker.is_alive() and free(port)


def test_a_busy_port_is_one_line(avatar_dir, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["view", str(avatar_dir), "--port", str(port)]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (f"trioman view: error: --port: 127.0.0.1:{port} is already in use (another viewer or "
                           f"server); pick another with --port, or --port 0 for any free one")


@pytest.mark.parametrize("damage, message", [
    (lambda d: d / "nothing", "avatar folder not found"),
    (lambda d: (d / "gaussians.npz").unlink() or d, "gaussians.npz: missing file"),
    (lambda d: edit_json(d, num_gaussians=3) or d, "num_gaussians"),
    (lambda d: None, "AVATAR: give an avatar folder (or --augmented DIR"),
])
def test_bad_avatar_folders_are_one_line(avatar_dir, capsys, damage, message):
    target = damage(avatar_dir)
    assert main(["view", *([str(target)] if target is not None else []), "--port", "0"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trioman view: error: ") and message in err and len(err.strip().splitlines()) == 1, err


def test_subject_cameras_and_augmented_output(avatar_dir, tmp_path):
    subject = make_subject(tmp_path / "subject")
    augmented = make_augment_output(tmp_path / "augmented", subject, avatar_dir)
    v = open_viewer(None, subject=subject, augmented=augmented, port=0)
    try:
        assert Path(v.poser.avatar.root).resolve() == avatar_dir.resolve()  # the run's avatar
        assert list(v.poser.catalog) == ["test poses: subject"]
        cams = v.subject_cameras
        assert list(cams.indices) == [0, 1, 2]  # the train frames
        side = cams.show(1)
        assert side.shape == (12, 32, 3)
        assert (np.abs(side[:, 16:] - 1.0).max(-1) > 0.1).any()  # the avatar in front of the white background
        assert "frame **000001**" in cams._caption.content
        view = v.augmented
        sheet = view.show("000002")
        images, labels = view.images(view.records[2])
        assert len(images) == 4 and labels == ["source 000002", "c0 0.200 not_chosen", "c1 0.700 accepted",
                                               "refined c1 (kept)"]
        assert sheet.ndim == 3 and "Examiner chose c1" in view._table.content
        assert len(view._frustums) == 2
    finally:
        v.stop()


def test_augmented_without_its_files_is_one_line(tmp_path, capsys):
    assert main(["view", "--augmented", str(tmp_path), "--port", "0"]) == 1
    assert f"{tmp_path / 'augment.json'}: missing file" in capsys.readouterr().err


def test_serves_and_poses_without_torch(avatar_dir):
    proc = run_python(f"""
        import sys, urllib.request
        from trioman.runtime.viewer.app import open_viewer
        v = open_viewer({str(avatar_dir)!r}, port=0)
        assert urllib.request.urlopen(v.url, timeout=10).status == 200
        v.controls.rest = True
        v.controls.bends = {{"root": 30.0}}
        assert set(v.refresh()) == {{"centers"}}
        v.stop()
        assert sys.modules.get('torch') is None
        print("ok")
    """, block_torch=True)
    assert proc.returncode == 0 and "ok" in proc.stdout, proc.stderr


def test_play_advances_the_frames_of_a_motion_file(avatar_dir, tmp_path):
    from trioman.runtime.formats.motion import save_motion
    from trioman.runtime.motions import Motion

    names = ("root", "mid", "tip")
    pose = np.zeros((5, 3, 3), np.float32)
    pose[:, 1, 0] = np.linspace(0, 1, 5)
    save_motion(tmp_path / "nod.npz", Motion("nod", pose, np.zeros((5, 3), np.float32), names, 20.0))
    v = open_viewer(avatar_dir, motion=str(tmp_path / "nod.npz"), port=0, fps=50.0)
    try:
        assert v.poser.name == "nod.npz" and v.poser.motion.num_frames == 5
        v.playing = True
        seen = set()
        start = time.perf_counter()
        while len(seen) < 3 and time.perf_counter() - start < 20:
            seen.add(v.controls.frame)
            time.sleep(0.01)
        assert len(seen) >= 3 and int(v._frame_slider.value) in range(5)
    finally:
        v.stop()


# ------------------------------------------------------------------------------------------------
# what the viewer may read, and where it listens (docs/design.md, "What a command may delete, and what it may read")


def _edit_record(augmented: Path, name: str, edit) -> Path:
    import json

    path = augmented / "records" / f"{name}.json"
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))
    return path


def _edit_settings(augmented: Path, edit) -> Path:
    import json

    path = augmented / "augment.json"
    meta = json.loads(path.read_text())
    edit(meta["settings"])
    path.write_text(json.dumps(meta))
    return path


@pytest.fixture
def augmented(avatar_dir, tmp_path):
    subject = make_subject(tmp_path / "subject")
    return make_augment_output(tmp_path / "augmented", subject, avatar_dir)


@pytest.mark.parametrize("where, edit, message", [
    ("000001", lambda r: r["frames"][0].update(name="../../../../outside"),
     "frames[0].name: '../../../../outside' is not a safe file stem"),
    ("000001", lambda r: r["source"].update(name="/etc/passwd"), "source.name: '/etc/passwd' is not a safe file stem"),
    ("000001", lambda r: r.update(seed="abc"), "seed: expected an integer >= 0, got 'abc'"),
    ("000001", lambda r: r.update(candidates=[{"candidate": 0}] * 2), "candidates[0]: expected candidate (int), status"),
    ("000001", lambda r: r["source"].update(index=7), "source: frame 7 '000001' is not a frame of the subject"),
    ("augment", lambda s: s["generator"].update(colour=1), "settings.generator: unknown key 'colour'"),
    ("augment", lambda s: s["generator"].update(min_distance=-1), "settings.generator: min_distance: must be a number"),
    ("augment", lambda s: s.update(per_frame=1e9), "settings.per_frame: expected an integer >= 1, got 1000000000.0"),
    ("augment", lambda s: s.update(per_frame=3), "candidates: expected a list of settings.per_frame = 3 candidates, got 2"),
], ids=["frame-outside", "source-absolute", "seed-text", "candidate-fields", "index", "generator-key",
        "generator-value", "per-frame-huge", "per-frame-count"])
def test_a_bad_augment_output_is_one_line_naming_the_file(augmented, capsys, where, edit, message):
    if where == "augment":
        path = _edit_settings(augmented, edit)
    else:
        path = _edit_record(augmented, where, edit)
    if "per_frame = 3" in message:
        path = augmented / "records" / "000000.json"
    assert main(["view", "--augmented", str(augmented), "--port", "0"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"trioman view: error: {path}: ") and message in err and len(err.strip().splitlines()) == 1, err


def test_a_deeply_nested_record_is_one_line(augmented, capsys):
    path = augmented / "records" / "000001.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    assert main(["view", "--augmented", str(augmented), "--port", "0"]) == 1
    assert capsys.readouterr().err.strip() == f"trioman view: error: {path}: malformed JSON: nested too deeply to read"


def test_a_kept_frame_linked_outside_the_folder_is_not_read(augmented, tmp_path):
    from trioman.runtime.formats import FormatError
    from trioman.runtime.image_io import write_png

    secret = tmp_path / "secret.png"
    write_png(secret, np.zeros((4, 4, 3), np.float32))
    link = augmented / "images" / "000002_c1.png"
    link.unlink()
    link.symlink_to(secret)
    v = open_viewer(None, augmented=augmented, port=0)
    try:
        v.augmented.show("000001")
        with pytest.raises(FormatError, match=r"000002\.json: frame '000002_c1': its file is a link that leads outside"):
            v.augmented.show("000002")
    finally:
        v.stop()


def test_an_images_folder_or_record_linked_outside_is_not_read(augmented, tmp_path, capsys):
    # issue 41, D8: with AUG/images itself a link outside, every frame read through it passed the check
    import shutil

    outside = tmp_path / "outside_images"
    shutil.move(augmented / "images", outside)
    (augmented / "images").symlink_to(outside, target_is_directory=True)
    assert main(["view", "--augmented", str(augmented), "--port", "0"]) == 1
    assert "its file is a link that leads outside" in capsys.readouterr().err
    (augmented / "images").unlink()
    shutil.move(outside, augmented / "images")
    record = augmented / "records" / "000001.json"
    shutil.move(record, tmp_path / "r.json")
    record.symlink_to(tmp_path / "r.json")
    assert main(["view", "--augmented", str(augmented), "--port", "0"]) == 1
    assert f"{record}: a link that leads outside" in capsys.readouterr().err


def test_an_address_this_machine_lacks_is_one_line(avatar_dir, capsys):
    from trioman.runtime.viewer.server import check_port

    with pytest.raises(ValueError, match="^host: 192.0.2.1 is not an address of this machine"):
        check_port("192.0.2.1", 0)  # TEST-NET-1: no machine has it
    assert main(["view", str(avatar_dir), "--host", "192.0.2.1", "--port", "0"]) == 1
    assert capsys.readouterr().err.startswith("trioman view: error: --host: 192.0.2.1 is not an address of this machine")


def test_every_address_is_said_once(avatar_dir, capsys):
    from trioman.runtime.viewer.server import is_local_only

    assert is_local_only("127.0.0.1") and is_local_only("localhost") and not is_local_only("0.0.0.0")
    assert main(["view", str(avatar_dir), "--host", "0.0.0.0", "--port", "0", "--time", "1"]) == 0
    out = capsys.readouterr().out
    assert out.count("--host 0.0.0.0 serves the avatar") == 1 and "to everyone who can reach this machine" in out
    assert main(["view", str(avatar_dir), "--port", "0", "--time", "1"]) == 0
    assert "serves the avatar" not in capsys.readouterr().out
