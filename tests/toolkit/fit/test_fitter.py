"""The fitter recovers a known synthetic pose and shape from perfect landmarks and masks; the landmarks' places
on Anny; the fit's evaluation against the truth."""

import dataclasses

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.runtime.cameras import project  # noqa: E402
from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.toolkit.fit.evaluate import JOINT_GROUPS, procrustes  # noqa: E402
from trioman.toolkit.fit.fitter import FitConfig, Observations, fit_sequence  # noqa: E402
from trioman.toolkit.fit.keypoints import correspondence  # noqa: E402
from trioman.toolkit.fit.sides import exchange_sides  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402

PA_MPJPE_MM = 40.0  # the stated tolerance on perfect observations (the target on real ones)


@pytest.fixture(scope="module")
def subject(tmp_path_factory):
    out = tmp_path_factory.mktemp("fit") / "s"
    synthesize_subject(SynthConfig(seed=3, size=128, frames=40, coverage=0.5, texture_size=256), out, progress=False)
    return load_subject(out)


def perfect_observations(s) -> Observations:
    """What a flawless person model would report on the training frames: the landmarks' true pixels, the true
    world landmarks (camera axes, from the hips' centre) and the true masks."""
    corr = correspondence(s.body)
    idx = s.indices("train")
    N = len(idx)
    kp, conf, world = np.zeros((N, 33, 2)), np.zeros((N, 33)), np.zeros((N, 33, 3))
    hips = [list(corr.landmarks).index(23), list(corr.landmarks).index(24)]
    for k, i in enumerate(idx):
        P = corr.points(s.body, s.poses_true[i].astype(np.float64), s.trans[i].astype(np.float64))
        kp[k, corr.landmarks] = project(P, s.viewmat[i].astype(np.float64), s.K[i].astype(np.float64))[0]
        conf[k, corr.landmarks] = 1.0
        cam = P @ s.viewmat[i][:3, :3].T.astype(np.float64)
        world[k, corr.landmarks] = cam - cam[hips].mean(0)
    masks = np.stack([s.mask(int(i)) for i in idx])
    return Observations(kp, conf, world, masks, np.arange(N), s.width, s.height)


def test_landmarks_sit_where_mediapipe_puts_them(anny_body):
    mesh = anny_body.to_skinned_mesh()
    c = correspondence(mesh)
    assert len(c.landmarks) == 27 and np.all((c.joint >= 0) ^ (c.vertex >= 0))
    v, sk = mesh.vertices, mesh.skeleton
    at = {int(m): (sk.joints[j] if j >= 0 else v[x]) for m, j, x in zip(c.landmarks, c.joint, c.vertex)}
    assert at[0][1] < at[2][1] and at[0][1] < at[5][1]  # the nose in front of the eyes (the body faces -y)
    assert at[7][0] > at[2][0] > 0 > at[5][0] > at[8][0]  # ears outside the eyes, the person's left at +x
    assert at[29][1] > at[27][1] > at[31][1] and at[29][2] < at[27][2]  # heel behind and below the ankle, toe in front
    assert at[11][0] > 0 > at[12][0] and at[23][2] < at[11][2]


def test_the_fitter_recovers_a_known_pose_and_shape(subject):
    """... from perfect landmarks of which the first frames are read mirrored (front taken for back), as MediaPipe
    reads some frames of a video: the fit gives them their sides back."""
    obs = perfect_observations(subject)
    mirrored = np.arange(len(obs.keypoints)) < 4  # the first frames face the camera
    obs = dataclasses.replace(obs, keypoints=exchange_sides(obs.keypoints, mirrored),
                              world=exchange_sides(obs.world, mirrored, world=True))
    result = fit_sequence(obs, subject.body, FitConfig(focal=float(subject.K[0, 0, 0]), key_iterations=300,
                                                       all_iterations=150))
    np.testing.assert_array_equal(result.mirrored, mirrored)
    assert result.reprojection_px.mean() < 2.0, result.reprojection_px
    names = [n for g in JOINT_GROUPS.values() for n in g]
    from trioman.toolkit.body.registry import create_body_model

    fitted = create_body_model("anny", phenotype=result.phenotype).to_skinned_mesh().skeleton
    sk = subject.body.skeleton
    errors = []
    for k, i in enumerate(subject.indices("train")):
        G = sk.forward_kinematics(subject.poses_true[i].astype(np.float64), subject.trans[i].astype(np.float64))
        a = G[[sk.index(n) for n in names], :3, 3] @ subject.viewmat[i][:3, :3].T.astype(np.float64)
        F = fitted.forward_kinematics(result.poses[k], result.trans[k])
        b = F[[fitted.index(n) for n in names], :3, 3] @ result.viewmat[:3, :3].T
        errors.append(np.linalg.norm(a - procrustes(a, b), axis=1).mean())
    assert 1000 * np.mean(errors) < PA_MPJPE_MM, f"PA-MPJPE {1000 * np.mean(errors):.1f} mm"
    assert all(np.isfinite(v) for v in result.losses.values())


def test_procrustes_undoes_a_similarity():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(14, 3))
    from trioman.runtime.rotations import axis_angle_to_matrix

    R = axis_angle_to_matrix(np.array([0.3, -1.2, 0.5]))
    b = 2.5 * a @ R.T + np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(procrustes(a, b), a, atol=1e-9)


@pytest.mark.parametrize("kwargs, field", [(dict(focal=-1.0), "focal"), (dict(keyframes=0), "keyframes"),
                                            (dict(all_iterations=1.5), "all_iterations"),
                                            (dict(w_world_shoulders=-0.1), "w_world_shoulders"),
                                            (dict(w_world_shoulders=float("nan")), "w_world_shoulders")])
def test_bad_fit_settings_are_named(kwargs, field):
    with pytest.raises(ValueError, match=f"^{field}: "):
        FitConfig(**kwargs)


def test_the_shoulders_world_weight_changes_only_the_shoulder_bones(anny_body, monkeypatch):
    """``w_world_shoulders`` weighs the world term's bones that end at a shoulder and no other: at 0 the term is the
    other bones' alone (their share of the mean as before), at ``w_world`` (or None) it is the default's exactly."""
    import torch

    from trioman.toolkit.fit import fitter
    from trioman.toolkit.fit.fitter import ACTIVE_JOINTS, _Body, _Problem

    base = anny_body.to_skinned_mesh()
    body = _Body(base, correspondence(base), 50, 0)
    rng = np.random.default_rng(2)
    N = 3
    obs = Observations(rng.uniform(0, 60, (N, 33, 2)), rng.uniform(0.5, 1, (N, 33)), rng.normal(size=(N, 33, 3)),
                       np.ones((N, 80, 60), np.float32), np.arange(N), 60, 80)
    joints, points = body.rest(torch.full((6,), 0.5))
    pose = torch.as_tensor(rng.normal(scale=0.3, size=(N, len(ACTIVE_JOINTS), 3)), dtype=torch.float32)
    trans = torch.as_tensor([[0.0, 3.0, 0.0]] * N)
    R, f, frames = fitter._camera(torch.tensor(0.0)), torch.tensor(70.0), torch.arange(N)

    def world(cfg):
        return float(_Problem(obs, body, cfg).loss(frames, joints, points, pose, trans, R, f, smooth=False)["world"])

    default = world(FitConfig())
    assert world(FitConfig(w_world_shoulders=0.5)) == default
    off, double = world(FitConfig(w_world_shoulders=0.0)), world(FitConfig(w_world_shoulders=1.0))
    assert off < default < double
    rest = tuple(limb for limb in fitter.LIMBS if not set(limb) & {11, 12})
    assert 0 < len(rest) < len(fitter.LIMBS)
    monkeypatch.setattr(fitter, "LIMBS", rest)
    alone = world(FitConfig())  # the other bones' mean, at w_world
    np.testing.assert_allclose(off, alone * len(rest) / 8, rtol=1e-6)
    np.testing.assert_allclose(double - off, 2 * (default - off), rtol=1e-5)  # linear in the shoulders' weight
    assert "world" not in _Problem(obs, body, FitConfig(w_world=0.0)).loss(frames, joints, points, pose, trans, R, f,
                                                                          smooth=False)


@pytest.mark.parametrize("offsets", ["none", "shipped", "random"])
def test_the_fit_poses_its_points_as_the_full_skeleton_does(anny_body, monkeypatch, offsets):
    """The fit's chain over the active joints alone (weights moved onto each joint's nearest active ancestor)
    equals the numpy FK + LBS of every joint (``Correspondence.points``), at random poses; with the landmarks'
    offsets from their joints too."""
    import torch

    from trioman.toolkit.fit import keypoints
    from trioman.toolkit.fit.fitter import ACTIVE_JOINTS, _Body

    rng = np.random.default_rng(2)
    table = {"none": {}, "shipped": keypoints.JOINT_OFFSETS,
             "random": {m: tuple(rng.normal(scale=0.04, size=3)) for m in keypoints.JOINT_LANDMARKS}}[offsets]
    monkeypatch.setattr(keypoints, "JOINT_OFFSETS", table)
    base = anny_body.to_skinned_mesh()
    body = _Body(base, correspondence(base), 300, 0)
    assert (np.abs(body.corr.offset).sum(1) > 0).sum() == len(table)
    pheno = torch.as_tensor([anny_body.phenotype[k] for k in ("gender", "age", "muscle", "weight", "height", "proportions")],
                            dtype=torch.float32)
    joints, points = body.rest(pheno)
    rng = np.random.default_rng(1)
    pose = torch.as_tensor(rng.normal(scale=0.5, size=(3, len(ACTIVE_JOINTS), 3)), dtype=torch.float32)
    trans = torch.as_tensor(rng.normal(size=(3, 3)), dtype=torch.float32)
    marks, sil, full = body.pose(joints, points, pose, trans)
    c = body.corr
    for k in range(3):
        p, t = full[k].numpy().astype(np.float64), trans[k].numpy().astype(np.float64)
        verts = base.pose(p, t)
        np.testing.assert_allclose(marks[k].numpy(), c.points(base, p, t), atol=2e-5)
        np.testing.assert_allclose(sil[k].numpy(), verts[body.sil], atol=2e-5)


def test_bad_observations_are_named():
    N = 2
    good = dict(keypoints=np.zeros((N, 33, 2)), confidence=np.ones((N, 33)), world=np.zeros((N, 33, 3)),
                masks=np.zeros((N, 8, 6), np.float32), frame_index=np.arange(N), width=6, height=8)
    with pytest.raises(ValueError, match="^keypoints: non-finite"):
        Observations(**{**good, "keypoints": np.full((N, 33, 2), np.nan)})
    with pytest.raises(ValueError, match=r"^confidence: expected shape \[2, 33\]"):
        Observations(**{**good, "confidence": np.ones((N, 32))})
    with pytest.raises(ValueError, match="^observations: no frame"):
        Observations(**{**good, "keypoints": np.zeros((0, 33, 2))})
    with pytest.raises(ValueError, match=r"^clip: expected \[2\] non-decreasing"):
        Observations(**{**good, "clip": np.array([1, 0])})
    with pytest.raises(ValueError, match=r"^clip: .*shape \[3\]"):
        Observations(**{**good, "clip": np.zeros(3, int)})


def test_keyframes_cover_every_clip():
    from trioman.toolkit.fit.fitter import _keyframes

    one = np.zeros(100, dtype=int)
    np.testing.assert_array_equal(_keyframes(one, 24), np.unique(np.linspace(0, 99, 24).round().astype(int)))
    clips = np.r_[np.zeros(80, int), np.ones(5, int), np.full(15, 2)]
    keys = _keyframes(clips, 10)
    assert set(clips[keys]) == {0, 1, 2} and np.all(np.diff(keys) > 0)
    assert (clips[keys] == 0).sum() == 8 and (clips[keys] == 1).sum() == 1


def test_clips_are_unmirrored_apart():
    """A clip filmed from behind after one from the front: the yaw jumps by pi at the cut, which within one clip
    would read as mirrored frames; as two clips it is two motions."""
    from trioman.toolkit.fit.fitter import _unmirrored

    rng = np.random.default_rng(0)
    N = 20
    world = np.zeros((N, 33, 3))
    yaw = np.r_[np.linspace(0.0, 0.3, 10), np.linspace(np.pi, np.pi + 0.3, 10)]
    for k, a in enumerate(yaw):  # shoulders and hips across the body, turned by the yaw about the vertical
        for left, right, y in ((11, 12, -0.5), (23, 24, 0.0)):
            side = np.array([np.cos(a), 0.0, -np.sin(a)]) * 0.2
            world[k, left], world[k, right] = side + [0, y, 0], -side + [0, y, 0]
    obs = Observations(rng.uniform(0, 100, (N, 33, 2)), np.ones((N, 33)), world, np.ones((N, 8, 8), np.float32),
                       np.arange(N), 100, 100)
    _, swapped_as_one = _unmirrored(obs)
    _, swapped_as_two = _unmirrored(dataclasses.replace(obs, clip=np.r_[np.zeros(10, int), np.ones(10, int)]))
    assert swapped_as_one.sum() == 10 and not swapped_as_two.any()


def test_the_turn_error_sees_what_procrustes_hides(subject):
    """A fit whose pelvis is turned 20 degrees about the vertical on a third of the frames and whose spine and
    hips are twisted back: no joint the errors are read on moves (Anny's hip joints hang from the pelvis' own, at the
    root), the turn error reads the pelvis' 20 degrees on those frames (median 0: the common part is the camera's)
    and the chest's nothing."""
    from trioman.runtime.rotations import axis_angle_to_matrix, matrix_to_axis_angle
    from trioman.toolkit.fit.evaluate import compare

    sk = subject.body.skeleton
    poses = subject.poses_true.astype(np.float64).copy()
    turned = np.arange(subject.num_frames) % 3 == 0
    turn = axis_angle_to_matrix(np.array([0.0, 0.0, np.radians(20.0)]))
    for i in np.flatnonzero(turned):
        root = axis_angle_to_matrix(poses[i, 0])
        poses[i, 0] = matrix_to_axis_angle(turn @ root)
        back = root.T @ turn.T @ root  # the root's children keep their orientation in the world
        for name in ("spine05", "pelvis.L", "pelvis.R"):
            j = sk.index(name)
            poses[i, j] = matrix_to_axis_angle(back @ axis_angle_to_matrix(poses[i, j]))
    fit = dataclasses.replace(subject, poses=poses.astype(np.float32))
    same = compare(dataclasses.replace(subject, poses=subject.poses_true), subject)
    assert same["pelvis_turn_p90_deg"] == same["chest_turn_p90_deg"] == 0.0
    scores = compare(fit, subject)
    assert scores["pelvis_turn_deg"] == 0.0 and abs(scores["pelvis_turn_p90_deg"] - 20.0) < 0.5, scores
    assert scores["chest_turn_p90_deg"] < 1.0 and scores["pa_mpjpe"] < 1.0 and scores["mpjpe"] < 1.0, scores
