"""The realistic synthetic style: the person mask covers hair and garments, the truth renderer re-makes the
stored frames, determinism per seed (and per worker count), the video, the room, bad styles named."""

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.runtime.mesh_raster import rasterize_mesh  # noqa: E402
from trioman.toolkit.synth.fabric import value_noise  # noqa: E402
from trioman.toolkit.synth.garments import BOTTOMS, HAIRSTYLES, TOPS, Outfit, dress  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, TruthRenderer, build_body, synthesize_subject  # noqa: E402

TINY = dict(size=64, frames=12, texture_size=256, style="realistic", outfit="longsleeve,skirt,long,none")


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("realistic")
    synthesize_subject(SynthConfig(seed=5, **TINY), root / "s", progress=False, video=root / "s.mp4", workers=2)
    return root


def test_the_person_mask_covers_hair_and_garments_beyond_the_body(made):
    """Pixels outside the naked body's silhouette are the person's (skirt, hair, loose sleeves) and masked."""
    s = load_subject(made / "s")
    outside = []
    for i in s.indices("train"):
        verts = s.posed_vertices(int(i), true_pose=True)
        frags = rasterize_mesh(verts, s.body.faces, s.viewmat[i].astype(np.float64), s.K[i].astype(np.float64), s.width, s.height)
        body = cv2.dilate((frags.face_id >= 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        mask = s.mask(int(i))
        outside.append(int(((mask > 0.5) & ~body).sum()))
        assert s.image(int(i))[mask == 0].max() == 0, "the subject's image is premultiplied: black off the person"
    assert min(outside) > 10, f"person pixels outside the body per frame: {outside}"


def test_the_truth_renderer_remakes_every_stored_frame(made):
    s = load_subject(made / "s")
    truth = TruthRenderer(s)
    for i in range(s.num_frames):
        frame, image, mask = truth.recorded(i)
        assert np.abs(np.rint(image * 255) / 255 - s.image(i)).max() <= 1 / 255 + 1e-6, f"frame {i}"
        assert np.abs(np.rint(mask * 255) / 255 - s.mask(i)).max() <= 1 / 255 + 1e-6, f"frame {i}"
    # the clean truth at a stored pose and camera: the same person, sharp, without the sensor
    i = int(s.indices("train")[3])
    rgb, cover = truth.render(s.poses_true[i], s.trans[i], s.viewmat[i], s.K[i])
    a, b = cover > 0.5, s.mask(i) > 0.5
    assert (a & b).sum() / (a | b).sum() > 0.8  # the stored frame's motion blur (<= 1.5 px) spreads a 64 px person
    core = cv2.erode((a & b).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.abs(rgb - s.image(i))[core].mean() < 0.08


def test_same_seed_same_bytes_whatever_the_worker_count(made, tmp_path):
    synthesize_subject(SynthConfig(seed=5, **TINY), tmp_path / "s", progress=False, video=tmp_path / "s.mp4", workers=1)
    assert digest(tmp_path / "s") == digest(made / "s")
    other = tmp_path / "other"
    synthesize_subject(SynthConfig(seed=6, **TINY), other, progress=False, workers=1)
    assert digest(other)["images/000000.png"] != digest(made / "s")["images/000000.png"]


def test_the_video_holds_the_training_frames_with_their_room(made):
    s = load_subject(made / "s")
    cap = cv2.VideoCapture(str(made / "s.mp4"))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr[..., ::-1] / 255.0)
    assert len(frames) == len(s.indices("train"))
    truth = TruthRenderer(s)
    for k in (0, len(frames) - 1):
        recorded, _, mask = truth.recorded(k)
        assert frames[k].shape == recorded.shape
        assert np.abs(frames[k] - recorded).mean() < 0.04  # the codec's loss
        room = recorded[mask == 0]
        assert room.std() > 0.05 and room.mean() > 0.2, "the room is behind the person, not black"


def test_steps_capture_walks_then_turns():
    from trioman.toolkit.synth.subject import plan_sequences

    cfg = SynthConfig(seed=5, size=64, frames=30, capture="steps")
    mesh, _ = build_body(cfg)
    seq = plan_sequences(mesh, cfg)
    train = np.asarray(seq.split) == "train"
    y = seq.trans[train, 1]
    assert y[0] - y[len(y) // 3 - 1] > 0.5  # walked towards the camera (-y)
    assert np.abs(np.diff(seq.trans[train, :2], axis=0)).max() < 0.1  # no jump between walk and turn
    yaw = seq.pose[train, 0, 2]
    assert yaw[-1] > 5.0 and np.all(yaw[: len(y) // 3] == 0)


@pytest.mark.parametrize("outfit", [Outfit(t, b, h, o) for t, b, h, o in
                                    [(TOPS[0], BOTTOMS[0], HAIRSTYLES[0], "none"), (TOPS[1], BOTTOMS[3], HAIRSTYLES[2], "none"),
                                     (TOPS[2], BOTTOMS[4], HAIRSTYLES[1], "none"), (TOPS[0], BOTTOMS[1], HAIRSTYLES[3], "coat")]])
def test_every_piece_is_skinned_and_outside_the_body(anny_body, outfit):
    body = anny_body.to_skinned_mesh()
    dressed = dress(body, outfit)
    mesh = dressed.mesh
    np.testing.assert_allclose(mesh.skin_weights.sum(1), 1.0, atol=1e-5)
    assert mesh.num_vertices > body.num_vertices and len(dressed.face_piece) == len(mesh.faces)
    np.testing.assert_array_equal(mesh.vertices[: body.num_vertices], body.vertices)
    # pieces stand off the skin: their vertices lie at least a few millimetres from every body vertex
    extra = mesh.vertices[body.num_vertices:]
    sub = body.vertices[::3]
    nearest = np.sqrt(((extra[::7, None] - sub[None]) ** 2).sum(-1)).min(1)
    assert np.median(nearest) > 0.006


def test_value_noise_is_a_function_of_position():
    p = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    a, b = value_noise(p, 0.05, 3), value_noise(p[::-1], 0.05, 3)[::-1]
    np.testing.assert_array_equal(a, b)
    assert a.min() >= 0 and a.max() <= 1 and a.std() > 0.05
    assert not np.array_equal(a, value_noise(p, 0.05, 4))


@pytest.mark.parametrize("kwargs, field", [
    (dict(style="fancy"), "style"), (dict(capture="dance"), "capture"), (dict(aspect=10.0), "aspect"),
    (dict(aspect=0.2), "aspect"), (dict(handheld_deg=-1.0), "handheld_deg"), (dict(style="realistic", outfit="a,b"), "outfit"),
    (dict(style="realistic", outfit="tshirt,kilt,short,none"), "outfit"), (dict(outfit="tshirt,skirt,short,none"), "outfit"),
])
def test_bad_styles_and_ranges_are_named(kwargs, field):
    with pytest.raises(ValueError, match=f"^{field}: "):
        SynthConfig(**kwargs)


def test_the_command_names_the_flag(tmp_path):
    from tests.conftest import run_python

    for args, flag in ((["--style", "realistic", "--outfit", "tshirt,kilt,short,none"], "--outfit"),
                       (["--aspect", "1:9"], "--aspect"), (["--handheld", "9"], "--handheld")):
        out = run_python(f"import sys; from trioman.cli import main; sys.exit(main(['synth', '--out', {str(tmp_path / 'x')!r}, *{args!r}]))")
        assert out.returncode != 0
        lines = [line for line in out.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"trioman synth: error: {flag}: "), out.stderr
    assert not (tmp_path / "x").exists()


def test_a_video_inside_the_subject_is_refused(tmp_path):
    with pytest.raises(ValueError, match="^video: "):
        synthesize_subject(SynthConfig(seed=5, **TINY), tmp_path / "s", progress=False, video=tmp_path / "s" / "v.mp4")
    assert not (tmp_path / "s").exists()
