"""The Anny body fitted to a whole video's person observations: one shape, one camera, a pose and a root per frame.

Objective (docs/fit.md, "The fit"), every term normalised by the person's height in pixels so weights do not
depend on the resolution:

- keypoints: confidence-weighted pseudo-Huber reprojection of the 27 landmarks with a place on the body
  (``toolkit/fit/keypoints.py``);
- silhouette: body points must project inside the person mask (one-sided: hair and clothes make the person
  larger than the body, never smaller), the squared distance to the mask sampled on a distance map;
- world landmarks: the 3D directions of the legs and torso (MediaPipe's metric landmarks, camera axes) against
  the body's, ``1 - cos``;
- temporal smoothness: the acceleration of the landmarks' 3D positions between neighbouring kept frames;
- priors: the pose's squared angles, knees and elbows bending one way only, an upright root, the shape near
  Anny's mean, the focal near its prior.

Frames the pose model read mirrored (front taken for back) get their sides exchanged first (``sides.py``).
Coarse to fine: stage 1 fits shape, focal, camera pitch and the poses of ``keyframes`` frames spread over the
video; stage 2 freezes them and fits every frame's pose and root from the nearest keyframe's, all frames at
once with the smoothness term. The camera stands at the world origin, level but for the fitted pitch, looking
along +y; the world is z-up, the subject's first frame facing the camera (-y), as the subject format wants.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from trioman.runtime.rotations import axis_angle_to_matrix as np_aa_to_matrix
from trioman.toolkit.fit.config import FitConfig
from trioman.runtime.rotations import matrix_to_axis_angle as np_matrix_to_aa
from trioman.runtime.skeleton import SkinnedMesh
from trioman.toolkit.body.anny_model import PHENOTYPE_LABELS
from trioman.toolkit.body.skinning import skinning_transforms
from trioman.toolkit.fit.keypoints import LIMBS, Correspondence, correspondence
from trioman.toolkit.fit.sides import body_yaw, exchange_sides, swapped_frames
from trioman.toolkit.rotations import axis_angle_to_matrix

# the prior's weight per active joint (after the root): the spine and neck bend little, the limbs freely
STIFF = {"spine04": 20.0, "spine02": 20.0, "neck01": 10.0, "head": 5.0, "wrist.L": 3.0, "wrist.R": 3.0, "foot.L": 3.0,
         "foot.R": 3.0}
ACTIVE_JOINTS = ("root", "spine04", "spine02", "neck01", "head", "upperarm01.L", "upperarm01.R", "lowerarm01.L",
                 "lowerarm01.R", "wrist.L", "wrist.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R",
                 "foot.L", "foot.R")
PHONE_FOCAL = 0.722  # a phone's main camera (26 mm equivalent): focal in units of the image's long side
# world -> camera of a level camera looking along +y: x_cam = x, y_cam = -z (image down), z_cam = y (depth)
LEVEL_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
BODY_HEIGHT = 1.7  # m, the prior person height for the first depth guess
DIST_MAP_SIDE = 256  # the silhouette distance maps' long side (pixels)
MAX_PITCH = math.radians(35.0)
REPAIR_FACTOR, REPAIR_FLOOR = 3.0, 0.02  # a keyframe whose landmark error (person heights) exceeds both is restarted


@dataclass(frozen=True, eq=False)
class Observations:
    """What the person model saw in the kept frames of a video (N frames of one size)."""

    keypoints: np.ndarray  # [N, 33, 2] pixels
    confidence: np.ndarray  # [N, 33] in [0, 1]
    world: np.ndarray  # [N, 33, 3] metres, camera axes (zeros: unknown)
    masks: np.ndarray  # [N, h, w] float32 person masks (any size of the frame's aspect)
    frame_index: np.ndarray  # [N] the frames' numbers in the video (neighbours in time are smoothed together)
    width: int
    height: int
    # [N] int: the clip (shot) of each frame in a video of several; frames of different clips are neither smoothed
    # together, read as one turn for the mirrored-frame search, nor started from each other's keyframes. None: one clip
    clip: np.ndarray | None = None

    def __post_init__(self) -> None:
        N = len(self.keypoints)
        if N < 1:
            raise ValueError("observations: no frame to fit")
        for name, arr, shape in (("keypoints", self.keypoints, (N, 33, 2)), ("confidence", self.confidence, (N, 33)),
                                 ("world", self.world, (N, 33, 3)), ("frame_index", self.frame_index, (N,))):
            if np.shape(arr) != shape:
                raise ValueError(f"{name}: expected shape {list(shape)}, got {list(np.shape(arr))}")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name}: non-finite values")
        if np.ndim(self.masks) != 3 or len(self.masks) != N:
            raise ValueError(f"masks: expected [{N}, h, w], got {list(np.shape(self.masks))}")
        if self.clip is not None and (np.shape(self.clip) != (N,) or np.any(np.diff(np.asarray(self.clip)) < 0)):
            raise ValueError(f"clip: expected [{N}] non-decreasing clip numbers, got shape {list(np.shape(self.clip))}: "
                             f"{np.asarray(self.clip).ravel()[:8].tolist()}")

    @property
    def clips(self) -> np.ndarray:
        """[N] int: the clip of each frame (0 everywhere for one clip)."""
        return np.zeros(len(self.keypoints), dtype=np.int64) if self.clip is None else np.asarray(self.clip, dtype=np.int64)


@dataclass(frozen=True, eq=False)
class FitResult:
    phenotype: dict[str, float]
    poses: np.ndarray  # [N, J, 3] axis-angle, Anny's joints
    trans: np.ndarray  # [N, 3]
    viewmat: np.ndarray  # [4, 4] world -> camera, every frame
    K: np.ndarray  # [3, 3]
    reprojection_px: np.ndarray  # [N] confidence-weighted mean landmark error
    losses: dict[str, float]  # the final terms of stage 2
    mirrored: np.ndarray  # [N] bool: frames whose left and right landmarks were exchanged before the fit


class _Body:
    """Anny's rest geometry as a function of the phenotype, and the points the fit poses."""

    def __init__(self, base: SkinnedMesh, corr: Correspondence, points: int, seed: int):
        import anny

        model = anny.Anny(skinning_method="lbs").to(torch.float32)
        model.reference_bone_orientations = None
        self.model = model
        self.parents = [int(p) for p in base.skeleton.parents]
        self.names = list(base.skeleton.joint_names)
        self.corr = corr
        rng = np.random.default_rng(seed)
        self.sil = np.sort(rng.choice(base.num_vertices, size=min(points, base.num_vertices), replace=False))
        vert_ids = np.concatenate([corr.vertex[corr.vertex >= 0], self.sil])
        self.vert_ids = torch.as_tensor(vert_ids)
        self.template = model.template_vertices[self.vert_ids].clone()  # [P, 3]
        self.shapes = model.blendshapes[:, self.vert_ids].clone()  # [C, P, 3]
        self.n_mark_verts = int((corr.vertex >= 0).sum())
        self.active = torch.as_tensor([self.names.index(n) for n in ACTIVE_JOINTS])
        # A joint left at the zero pose has its parent's skinning transform (A_c = G_p [I | j_c - j_p] [I | -j_c]
        # = A_p), so every other joint's weights move onto its nearest active ancestor and the kinematic chain runs
        # over the active joints alone: the same LBS, exactly, at a sixth of the cost.
        position = {int(j): a for a, j in enumerate(self.active.tolist())}
        owner = np.empty(len(self.names), dtype=np.int64)
        for j in range(len(self.names)):
            k = j
            while k not in position:
                k = self.parents[k]
            owner[j] = position[k]
        self.owner = torch.as_tensor(owner)
        self.active_parents = [-1] + [int(owner[self.parents[int(j)]]) for j in self.active.tolist()[1:]]
        dense = np.zeros((len(vert_ids), len(ACTIVE_JOINTS)), np.float32)
        np.add.at(dense, (np.arange(len(vert_ids))[:, None], owner[base.skin_indices[vert_ids]]), base.skin_weights[vert_ids])
        self.point_weights = torch.as_tensor(dense)  # [P, A]

    def rest(self, pheno: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """pheno [6] in (0, 1) -> rest joints [J, 3], rest points [P, 3] (vertex landmarks, then silhouette points):
        Anny's phenotype blend shapes on these points alone (its rest model, without posing the whole mesh)."""
        m = self.model
        _, params, local, face = m.get_tensor_inputs(None, pheno[None], None, None)
        coeffs = m._get_phenotype_blendshape_coefficients(params, local, face)[0]  # [C]
        joints = m.template_bone_heads + torch.einsum("cpd,c->pd", m.bone_heads_blendshapes, coeffs)
        points = self.template + torch.einsum("cpd,c->pd", self.shapes, coeffs)
        return joints, points

    def pose(self, joints: torch.Tensor, points: torch.Tensor, active_pose: torch.Tensor, trans: torch.Tensor):
        """-> (landmarks [B, M, 3] world, silhouette points [B, S, 3] world, full pose [B, J, 3])."""
        B = len(active_pose)
        full = torch.zeros(B, len(self.names), 3, dtype=active_pose.dtype)
        full[:, self.active] = active_pose
        A = skinning_transforms(self.active_parents, joints[self.active], active_pose, trans)  # [B, A, 4, 4]
        T = torch.einsum("pa,baij->bpij", self.point_weights, A[..., :3, :])  # [B, P, 3, 4]
        posed_points = (T[..., :3] @ points[..., None])[..., 0] + T[..., 3]
        corr = self.corr
        marks = torch.empty(B, len(corr.landmarks), 3, dtype=active_pose.dtype)
        is_joint = corr.joint >= 0
        j = torch.as_tensor(corr.joint[is_joint])
        Aj = A[:, self.owner[j]]  # [B, Mj, 4, 4]: each landmark joint moves with its active ancestor
        at = joints[j] + torch.as_tensor(corr.offset[is_joint], dtype=joints.dtype)
        marks[:, torch.as_tensor(is_joint)] = Aj[..., :3, 3] + (Aj[..., :3, :3] @ at[..., None])[..., 0]
        marks[:, torch.as_tensor(~is_joint)] = posed_points[:, : self.n_mark_verts]
        return marks, posed_points[:, self.n_mark_verts:], full


def _camera(raw_pitch: torch.Tensor) -> torch.Tensor:
    """World -> camera rotation [3, 3] of a level camera looking along +y, tilted by the pitch
    ``MAX_PITCH tanh(raw_pitch)`` (rad): a person filming a person holds the phone within it of level."""
    pitch = MAX_PITCH * torch.tanh(raw_pitch)
    c, s = torch.cos(pitch), torch.sin(pitch)
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    Rx = torch.stack([torch.stack([one, zero, zero]), torch.stack([zero, c, -s]), torch.stack([zero, s, c])])
    return Rx @ torch.as_tensor(LEVEL_CAMERA, dtype=pitch.dtype)


def _distance_maps(masks: np.ndarray) -> np.ndarray:
    """Per frame, the distance from each pixel to the person mask (0 inside), in units of the map's long side,
    at most DIST_MAP_SIDE pixels on that side. -> [N, h, w] float32"""
    h, w = masks.shape[1:]
    scale = min(1.0, DIST_MAP_SIDE / max(h, w))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    out = []
    for m in masks:
        small = cv2.resize(m.astype(np.float32), size, interpolation=cv2.INTER_AREA) if scale < 1 else m
        d = cv2.distanceTransform((small < 0.5).astype(np.uint8), cv2.DIST_L2, 5)
        out.append(d / max(size))
    return np.stack(out).astype(np.float32)


def _unmirrored(obs: Observations) -> tuple[Observations, np.ndarray]:
    """``obs`` with the frames read mirrored given their sides back. -> (observations, bool [N])"""
    clips = obs.clips
    swap = np.zeros(len(clips), dtype=bool)
    for c in np.unique(clips):
        swap[clips == c] = swapped_frames(obs.world[clips == c], obs.frame_index[clips == c])
    if not swap.any():
        return obs, swap
    return dataclasses.replace(obs, keypoints=exchange_sides(obs.keypoints, swap),
                               confidence=exchange_sides(obs.confidence, swap),
                               world=exchange_sides(obs.world, swap, world=True)), swap


def _height_px(obs: Observations) -> np.ndarray:
    """Each frame's person height in pixels (its mask's rows, else the landmarks' span). -> [N]"""
    out = []
    sy = obs.height / obs.masks.shape[1]
    for k, m in enumerate(obs.masks):
        rows = np.flatnonzero(m.max(axis=1) >= 0.5)
        if len(rows) > 1:
            out.append((rows[-1] - rows[0] + 1) * sy)
        else:
            ys = obs.keypoints[k, obs.confidence[k] > 0.5, 1]
            out.append(1.15 * np.ptp(ys) if len(ys) > 1 else 0.5 * obs.height)
    return np.maximum(np.array(out), 8.0)


class _Problem:
    """The observations as tensors, the loss of a set of frames."""

    def __init__(self, obs: Observations, body: _Body, cfg: FitConfig):
        self.obs, self.body, self.cfg = obs, body, cfg
        self.clips = obs.clips
        corr = body.corr
        self.kp = torch.as_tensor(obs.keypoints[:, corr.landmarks], dtype=torch.float32)
        self.conf = torch.as_tensor(obs.confidence[:, corr.landmarks] * corr.weight, dtype=torch.float32)
        self.height_px = torch.as_tensor(_height_px(obs), dtype=torch.float32)
        self.dist = torch.as_tensor(_distance_maps(obs.masks))[:, None]  # [N, 1, h, w]
        self.world = torch.as_tensor(obs.world, dtype=torch.float32)
        self.world_conf = torch.as_tensor(obs.confidence, dtype=torch.float32)
        idx = {int(m): k for k, m in enumerate(corr.landmarks)}
        self.limbs = [(idx[a], idx[b], a, b) for a, b in LIMBS if a in idx and b in idx]
        shoulders = cfg.w_world if cfg.w_world_shoulders is None else cfg.w_world_shoulders
        self.limb_weights = [shoulders if {a, b} & {11, 12} else cfg.w_world for _, _, a, b in self.limbs]
        self.shoulders, self.hips = [idx[11], idx[12]], [idx[23], idx[24]]
        self.knee = [body.names.index(n) for n in ("lowerleg01.L", "lowerleg01.R")]
        self.elbow = [body.names.index(n) for n in ("lowerarm01.L", "lowerarm01.R")]
        self.cx, self.cy = obs.width / 2, obs.height / 2
        self.stiff = torch.as_tensor([STIFF.get(n, 1.0) for n in ACTIVE_JOINTS[1:]])

    def project(self, X: torch.Tensor, R: torch.Tensor, f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cam = X @ R.T
        z = cam[..., 2].clamp(min=1e-3)
        return torch.stack([f * cam[..., 0] / z + self.cx, f * cam[..., 1] / z + self.cy], -1), cam

    def frame_error(self, frames: torch.Tensor, joints, points, active_pose, trans, R, f) -> torch.Tensor:
        """Each frame's confidence-weighted landmark error in person heights. -> [B]"""
        marks, _, _ = self.body.pose(joints, points, active_pose, trans)
        uv, _ = self.project(marks, R, f)
        r = (uv - self.kp[frames]).norm(dim=-1) / self.height_px[frames][:, None]
        conf = self.conf[frames]
        return (r * conf).sum(1) / conf.sum(1).clamp(min=1e-6)

    def loss(self, frames: torch.Tensor, joints, points, active_pose, trans, R, f, smooth: bool) -> dict[str, torch.Tensor]:
        cfg, body = self.cfg, self.body
        marks, sil, full = body.pose(joints, points, active_pose, trans)
        uv, cam = self.project(marks, R, f)
        scale = self.height_px[frames][:, None]
        r = ((uv - self.kp[frames]).norm(dim=-1) / scale)
        c = 0.02
        conf = self.conf[frames]
        terms = {"keypoints": ((torch.sqrt(r * r + c * c) - c) * conf).sum() / conf.sum().clamp(min=1e-6)}
        suv, _ = self.project(sil, R, f)
        grid = torch.stack([suv[..., 0] / self.obs.width * 2 - 1, suv[..., 1] / self.obs.height * 2 - 1], -1)
        d = F.grid_sample(self.dist[frames], grid[:, None], align_corners=False, padding_mode="border")[:, 0, 0]
        long_side = max(self.obs.width, self.obs.height)
        terms["silhouette"] = cfg.w_silhouette * ((d * long_side / scale) ** 2).mean()
        if max(self.limb_weights, default=0.0) > 0:
            wl = []
            for i, j, a, b in self.limbs:
                mp = self.world[frames, b] - self.world[frames, a]
                model = cam[:, j] - cam[:, i]
                ok = (self.world_conf[frames, a] * self.world_conf[frames, b]) * (mp.norm(dim=-1) > 1e-6)
                cos = F.cosine_similarity(model, mp, dim=-1, eps=1e-6)
                wl.append(((1 - cos) * ok).sum() / ok.sum().clamp(min=1e-6))
            if len(set(self.limb_weights)) == 1:  # one weight for every bone (the default): as it always was
                terms["world"] = self.limb_weights[0] * torch.stack(wl).mean()
            else:  # each bone at its weight, over all of them: a bone at 0 leaves the others' share as it was
                terms["world"] = (torch.stack(wl) * torch.as_tensor(self.limb_weights)).mean()
        if smooth and len(frames) > 2:
            gap = torch.as_tensor(np.diff(self.obs.frame_index[frames.numpy()]))
            one = torch.as_tensor(np.diff(self.clips[frames.numpy()]) == 0)
            steady = ((gap[1:] == gap[:-1]) & one[1:] & one[:-1]).float()  # equal spacing, one clip: a true neighbour triple
            acc = marks[2:] - 2 * marks[1:-1] + marks[:-2]
            terms["smooth"] = cfg.w_smooth * ((acc ** 2).sum(-1).mean(-1) * steady).sum() / steady.sum().clamp(min=1)
        body_pose = active_pose[:, 1:]
        terms["pose"] = cfg.w_pose * ((body_pose ** 2).sum(-1) * self.stiff).mean()
        terms["limits"] = cfg.w_limits * (F.relu(-full[:, self.knee, 0] - 0.05) ** 2 + F.relu(full[:, self.elbow, 0] - 0.05) ** 2).mean()
        # upright: the root, and the torso (hips' centre to shoulders' centre) on average over the frames; the
        # camera's pitch could otherwise trade against a body leaning on every frame
        up = axis_angle_to_matrix(active_pose[:, 0])[:, 2, 2]
        torso = (marks[:, self.shoulders].mean(1) - marks[:, self.hips].mean(1)).mean(0)
        terms["upright"] = cfg.w_upright * ((1 - up).mean() + (1 - torso[2] / torso.norm().clamp(min=1e-6)))
        return terms


def _init_trans(obs: Observations, f: float, joints0: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Each frame's root translation from the hips' pixel and the person's pixel height. -> [N, 3]"""
    depth = f * BODY_HEIGHT / _height_px(obs)
    hips = 0.5 * (obs.keypoints[:, 23] + obs.keypoints[:, 24])
    cam = np.stack([(hips[:, 0] - obs.width / 2) * depth / f, (hips[:, 1] - obs.height / 2) * depth / f, depth], 1)
    world = cam @ R  # camera -> world (R is world -> camera)
    return world - joints0


def _keyframes(clips: np.ndarray, count: int) -> np.ndarray:
    """Positions of about ``count`` keyframes spread over the frames, each clip's share by its length and at least
    one in every clip. clips [N] (non-decreasing) -> sorted int positions."""
    N = len(clips)
    keys = []
    for c in np.unique(clips):
        at = np.flatnonzero(clips == c)
        n = max(1, min(len(at), round(count * len(at) / N)))
        keys.append(at[np.unique(np.linspace(0, len(at) - 1, n).round().astype(int))])
    return np.concatenate(keys)


def fit_sequence(obs: Observations, base: SkinnedMesh, cfg: FitConfig | None = None,
                 progress=None) -> FitResult:
    """Fit Anny to ``obs``; ``base`` is Anny's default body (its topology, weights and skeleton); ``progress``:
    a callable (stage, iteration, total) or None."""
    cfg = cfg if cfg is not None else FitConfig()
    torch.manual_seed(cfg.seed)
    obs, mirrored = _unmirrored(obs)
    corr = correspondence(base)
    body = _Body(base, corr, cfg.silhouette_points, cfg.seed)
    prob = _Problem(obs, body, cfg)
    N = len(obs.keypoints)
    f0 = cfg.focal if cfg.focal is not None else PHONE_FOCAL * max(obs.width, obs.height)
    log_f = torch.tensor(math.log(f0), requires_grad=cfg.refine_focal)
    pitch = torch.zeros((), requires_grad=True)
    known = cfg.phenotype is not None
    start = torch.as_tensor(cfg.phenotype, dtype=torch.float32).clamp(1e-4, 1 - 1e-4) if known else torch.full((6,), 0.5)
    pheno_logit = torch.logit(start).requires_grad_(not known)
    yaw = np.nan_to_num(body_yaw(obs.world))
    clips = obs.clips
    R0 = LEVEL_CAMERA
    trans0 = _init_trans(obs, f0, base.skeleton.joints[0], R0)

    # stage 1: keyframes, shape, focal, pitch
    keys = _keyframes(obs.clips, cfg.keyframes)
    k_pose = torch.zeros(len(keys), len(ACTIVE_JOINTS), 3)
    k_pose[:, 0, 2] = torch.as_tensor(yaw[keys], dtype=torch.float32)
    k_pose.requires_grad_(True)
    k_trans = torch.as_tensor(trans0[keys], dtype=torch.float32).clone().requires_grad_(True)
    params = [k_pose, k_trans, pitch] + ([] if known else [pheno_logit]) + ([log_f] if cfg.refine_focal else [])
    frames = torch.as_tensor(keys)

    def closure() -> torch.Tensor:
        for p in params:
            p.grad = None
        joints, points = body.rest(torch.sigmoid(pheno_logit))
        terms = prob.loss(frames, joints, points, k_pose, k_trans, _camera(pitch), log_f.exp(), smooth=False)
        dev = (torch.sigmoid(pheno_logit) - 0.5).pow(2)
        terms["shape"] = cfg.w_shape * dev.sum() + cfg.w_height * dev[PHENOTYPE_LABELS.index("height")]
        terms["focal"] = cfg.w_focal * (log_f - math.log(f0)) ** 2
        total = sum(terms.values())
        total.backward()
        return total

    # L-BFGS with a line search (SMPLify's choice): the keyframes' problem is small and badly conditioned. First
    # the root, translation and camera alone (the body at rest), so that no joint takes the body's orientation.
    rounds = max(2, cfg.key_iterations // 20)
    body_free = torch.zeros(len(ACTIVE_JOINTS), 1)
    body_free[0] = 1.0
    k_pose.register_hook(lambda g: g * body_free)

    def run(rounds: int, tag: str) -> None:
        opt = torch.optim.LBFGS(params, lr=1.0, max_iter=20, history_size=20, line_search_fn="strong_wolfe")
        for it in range(rounds):
            opt.step(closure)
            if progress is not None:
                progress(tag, it + 1, rounds)

    run(max(1, rounds // 3), "keyframes: root")
    body_free[1:] = 1.0
    run(rounds - rounds // 3, "keyframes")
    # A shared line search can leave a keyframe in a poor minimum: such keyframes restart from their best
    # neighbour's pose (turned by the difference of the yaw guesses) and the keyframes are fitted again.
    for _ in range(cfg.repairs):
        with torch.no_grad():
            joints, points = body.rest(torch.sigmoid(pheno_logit))
            err = prob.frame_error(frames, joints, points, k_pose, k_trans, _camera(pitch), log_f.exp()).numpy()
        bad = err > max(REPAIR_FACTOR * float(np.median(err)), REPAIR_FLOOR)
        if not bad.any() or bad.all():
            break
        good = np.flatnonzero(~bad)
        with torch.no_grad():
            for k in np.flatnonzero(bad):
                g = good[np.argmin(np.abs(good - k) + N * (clips[keys[good]] != clips[keys[k]]))]
                turn = np_aa_to_matrix(np.array([0.0, 0.0, yaw[keys[k]] - yaw[keys[g]]]))
                pose = k_pose[g].numpy().astype(np.float64).copy()
                pose[0] = np_matrix_to_aa(turn @ np_aa_to_matrix(pose[0]))
                k_pose[k] = torch.as_tensor(pose, dtype=torch.float32)
                k_trans[k] = k_trans[g] + torch.as_tensor(trans0[keys[k]] - trans0[keys[g]], dtype=torch.float32)
        run(max(1, rounds // 2), "keyframes: repair")

    # stage 2: every frame from its nearest keyframe; shape, focal and pitch frozen
    with torch.no_grad():
        pheno = torch.sigmoid(pheno_logit).clone()
        joints, points = body.rest(pheno)
        R, f = _camera(pitch).clone(), log_f.exp().clone()
    nearest = (np.abs(np.arange(N)[:, None] - keys[None]) + N * (clips[:, None] != clips[keys][None])).argmin(1)
    k_np = k_pose.detach().numpy().astype(np.float64)
    turn = np_aa_to_matrix(np.stack([np.zeros(N), np.zeros(N), yaw - yaw[keys][nearest]], 1))
    root = np_matrix_to_aa(turn @ np_aa_to_matrix(k_np[nearest, 0]))
    a_pose = torch.as_tensor(np.concatenate([root[:, None], k_np[nearest, 1:]], 1), dtype=torch.float32).requires_grad_(True)
    t_init = _init_trans(obs, float(f), joints[0].numpy().astype(np.float64), R.numpy().astype(np.float64))
    t_init += k_trans.detach().numpy()[nearest] - t_init[keys][nearest]  # the keyframe's fit, moved as the hips moved
    a_trans = torch.as_tensor(t_init, dtype=torch.float32).requires_grad_(True)
    opt = torch.optim.Adam([a_pose, a_trans], lr=cfg.lr / 4)  # from the keyframes' fit: small steps
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.all_iterations, eta_min=cfg.lr * 0.005)
    every = torch.arange(N)
    for it in range(cfg.all_iterations):
        opt.zero_grad()
        terms = prob.loss(every, joints, points, a_pose, a_trans, R, f, smooth=True)
        sum(terms.values()).backward()
        opt.step()
        sched.step()
        if progress is not None:
            progress("all frames", it + 1, cfg.all_iterations)

    with torch.no_grad():
        marks, _, full = body.pose(joints, points, a_pose, a_trans)
        uv, _ = prob.project(marks, R, f)
        err = (uv - prob.kp).norm(dim=-1)
        conf = prob.conf
        reproj = (err * conf).sum(1) / conf.sum(1).clamp(min=1e-6)
    viewmat = np.eye(4)
    viewmat[:3, :3] = R.numpy()
    fx = float(f)
    K = np.array([[fx, 0.0, obs.width / 2], [0.0, fx, obs.height / 2], [0.0, 0.0, 1.0]])
    return FitResult(
        phenotype={k: round(float(v), 4) for k, v in zip(PHENOTYPE_LABELS, pheno.numpy())},
        poses=full.numpy().astype(np.float64), trans=a_trans.detach().numpy().astype(np.float64), viewmat=viewmat, K=K,
        reprojection_px=reproj.numpy().astype(np.float64), losses={k: float(v.detach()) for k, v in terms.items()},
        mirrored=mirrored,
    )
