"""The Gaussian avatar (after ExAvatar; docs/design.md, "Baseline avatar").

One Gaussian per canonical body-mesh vertex (optionally subdivided or subsampled). A triplane is
sampled at the canonical positions and MLPs predict a position offset, a scale (isotropic by
default) and a colour; pose-dependent MLPs add offset/scale/colour deltas from the body pose, evaluated at
the Gaussians or at the vertices of a coarser subdivision level and carried to the Gaussians as the
subdivision carries positions (``pose_subdivisions``).
Opacity is 1 and rotation the identity unless ``anisotropic``. Gaussians follow the body by LBS with
the body's skinning weights. Two sets come out of each forward pass, as in ExAvatar: "plain"
(pose-independent) and "refined" (with the pose-dependent deltas).
"""

from __future__ import annotations

import warnings
from typing import Callable, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.autograd.function import once_differentiable

from trioman.runtime.stages import stage
from trioman.runtime.skeleton import SkinnedMesh
from trioman.toolkit.avatar.config import AvatarConfig
from trioman.toolkit.avatar.mesh_ops import avatar_points, knn, level_interpolation
from trioman.toolkit.avatar.triplane import Triplane
from trioman.toolkit.body.skinning import apply_transforms, skinning_transforms
from trioman.toolkit.rotations import axis_angle_to_matrix, matrix_to_quat, matrix_to_rot6d, quat_to_matrix

# Joints whose rotations condition the pose-dependent MLPs: the body, not fingers, toes or eyes.
_NOT_CONDITIONING = ("finger", "metacarpal", "toe", "eye", "root")


class Gaussians(NamedTuple):
    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4] wxyz
    scales: torch.Tensor  # [N, 3]
    opacities: torch.Tensor  # [N]
    colors: torch.Tensor  # [N, 3]


class AvatarOutput(NamedTuple):
    plain: Gaussians
    refined: Gaussians
    offset: torch.Tensor  # [N, 3] pose-independent position offset (canonical)
    log_scale: torch.Tensor  # [N, S] pose-independent log-scale offset from the initial scale
    delta_offset: torch.Tensor  # [N, 3] pose-dependent offset (zeros without pose dependence)
    delta_rgb: torch.Tensor  # [N, 3] pose-dependent colour logits (zeros without pose dependence)


class PoseFree(NamedTuple):
    """What a forward pass computes before it reads the pose (``GaussianAvatar.pose_free``)."""

    geo: torch.Tensor  # [N, 3 + S (+ 4 anisotropic)] the geometry MLP's output: offset, log scale (, rotation)
    rgb_logit: torch.Tensor  # [N, 3] pose-independent colour logits
    pose_layers: list[torch.Tensor] | None  # the pose MLPs' first layers on the point features, [M, H] x 2 (None
    # without pose dependence)


def _mlp(in_dim: int, hidden: int, out_dim: int, layers: int = 2) -> nn.Sequential:
    mods: list[nn.Module] = []
    d = in_dim
    for _ in range(layers):
        mods += [nn.Linear(d, hidden), nn.ReLU()]
        d = hidden
    last = nn.Linear(d, out_dim)
    nn.init.zeros_(last.weight)
    nn.init.zeros_(last.bias)
    return nn.Sequential(*mods, last)


class PoseMLP(nn.Module):
    """MLP on [point features, pose features] whose first layer splits so the pose part is computed once."""

    def __init__(self, feat_dim: int, pose_dim: int, hidden: int, out_dim: int):
        super().__init__()
        self.feat_in = nn.Linear(feat_dim, hidden)
        self.pose_in = nn.Linear(pose_dim, hidden, bias=False)
        self.rest = _mlp(hidden, hidden, out_dim, layers=1)

    def forward(self, feats: torch.Tensor, pose_feat: torch.Tensor) -> torch.Tensor:
        return self.from_feat_in(self.feat_in(feats), pose_feat)

    def from_feat_in(self, feat_in: torch.Tensor, pose_feat: torch.Tensor) -> torch.Tensor:
        """feat_in: [N, H] the first layer's point part (``feat_in(feats)``) -> [N, out_dim]."""
        return self.rest(torch.relu(feat_in + self.pose_in(pose_feat)))


def _csr_mm(S: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """S [N, M] (sparse CSR) @ x [M, C] -> [N, C], as a weighted bag sum of x's rows per row of S (faster on
    the CPU than torch.sparse.mm for these few non-zeros per row)."""
    return F.embedding_bag(S.col_indices(), x, S.crow_indices(), mode="sum", per_sample_weights=S.values().to(x.dtype),
                           include_last_offset=True)


class _SparseProduct(torch.autograd.Function):
    """S @ x for a constant sparse S [N, M] (CSR) and x [M, C]; the backward multiplies by the transpose given
    with it (CSR, built once)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, S: torch.Tensor, St: torch.Tensor) -> torch.Tensor:
        ctx.St = St
        return _csr_mm(S, x)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: torch.Tensor):
        return _csr_mm(ctx.St, grad.contiguous()), None, None


class GaussianAvatar(nn.Module):
    def __init__(self, mesh: SkinnedMesh, cfg: AvatarConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg if cfg is not None else AvatarConfig()
        points, skin_idx, skin_w = avatar_points(mesh, cfg.subdivisions, cfg.keep, cfg.seed)
        nbr, dist = knn(points, cfg.knn)
        sk = mesh.skeleton
        self.parents = sk.parents.tolist()
        self.joint_names = sk.joint_names
        self.register_buffer("canonical", torch.from_numpy(points).float())
        self.register_buffer("skin_indices", torch.from_numpy(skin_idx).long())
        self.register_buffer("skin_weights", torch.from_numpy(skin_w).float())
        self.register_buffer("neighbors", torch.from_numpy(nbr))
        self.register_buffer("joints", torch.from_numpy(sk.joints).float())
        base = np.log(cfg.scale_init * dist.mean(axis=1).clip(1e-4, None))
        self.register_buffer("base_log_scale", torch.from_numpy(base).float()[:, None])
        cond = [j for j, n in enumerate(sk.joint_names) if not n.startswith(_NOT_CONDITIONING)]
        self.register_buffer("pose_joints", torch.tensor(cond, dtype=torch.long))
        if self.coarse_pose:  # derived from the mesh and the config: not in the state dict
            coarse, idx, w = level_interpolation(mesh, cfg.pose_subdivisions, cfg.subdivisions, cfg.keep, cfg.seed)
            self.register_buffer("coarse_points", torch.from_numpy(coarse).float(), persistent=False)
            self.register_buffer("pose_indices", torch.from_numpy(idx), persistent=False)
            self.register_buffer("pose_weights", torch.from_numpy(w), persistent=False)

        # Same seed, same initial weights, without touching the caller's global RNG.
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            center = 0.5 * (self.canonical.min(0).values + self.canonical.max(0).values)
            self.triplane = Triplane(cfg.triplane_channels, cfg.triplane_res, center, cfg.triplane_half_size)
            f = self.triplane.out_dim
            s = 3 if cfg.anisotropic else 1
            self.geo_net = _mlp(f, cfg.hidden, 3 + s + (4 if cfg.anisotropic else 0))
            self.rgb_net = _mlp(f, cfg.hidden, 3)
            if cfg.point_colors:
                self.point_rgb = nn.Parameter(torch.zeros(self.num_gaussians, 3))
            if cfg.pose_dependent:
                p = 6 * len(cond)
                self.geo_offset_net = PoseMLP(f, p, cfg.hidden, 3 + s)
                self.rgb_offset_net = PoseMLP(f, p, cfg.hidden, 3)

    @property
    def num_gaussians(self) -> int:
        return self.canonical.shape[0]

    @property
    def coarse_pose(self) -> bool:
        """Whether the pose-dependent MLPs run at a coarser level than the Gaussians (``pose_subdivisions``)."""
        return self.cfg.pose_dependent and self.cfg.pose_subdivisions is not None

    @property
    def pose_points(self) -> torch.Tensor:
        """[M, 3] the canonical points where the pose-dependent MLPs run (the Gaussians' own, M = N, or the coarse level's)."""
        return self.coarse_points if self.coarse_pose else self.canonical

    def carry_pose_deltas(self, deltas: torch.Tensor) -> torch.Tensor:
        """deltas [M, C] at ``pose_points`` -> [N, C] at the Gaussians: row n is ``sum_p pose_weights[n, p]
        deltas[pose_indices[n, p]]`` (one sparse product). Identity without ``coarse_pose``."""
        if not self.coarse_pose:
            return deltas
        carry = self._sparse("pose", (self.pose_indices, self.pose_weights),
                             lambda: (self.pose_indices, self.pose_weights, self.coarse_points.shape[0]))
        return _SparseProduct.apply(deltas, *carry)

    def pose_features(self, pose: torch.Tensor) -> torch.Tensor:
        """[J, 3] axis-angle -> [6 * J_cond], zero at the rest pose."""
        R = axis_angle_to_matrix(pose[self.pose_joints])
        eye = torch.eye(3, dtype=R.dtype, device=R.device)
        return (matrix_to_rot6d(R) - matrix_to_rot6d(eye)).reshape(-1)

    def rgb_logits(self, feats: torch.Tensor) -> torch.Tensor:
        """feats: [N, F] triplane features -> [N, 3] pose-independent colour logits."""
        return self._with_point_rgb(self.rgb_net(feats))

    def _with_point_rgb(self, logits: torch.Tensor) -> torch.Tensor:
        return logits + self.point_rgb if self.cfg.point_colors else logits

    def _first_layers(self) -> list[torch.Tensor]:
        """The first layers of the MLPs that read the triplane's features at the Gaussians, [N, H] each (geo,
        rgb, then the pose MLPs' point parts): one product for all of them, so the backward pass builds one
        gradient of the planes instead of summing one per MLP."""
        layers = [self.geo_net[0], self.rgb_net[0]]
        if self.cfg.pose_dependent and not self.coarse_pose:
            layers += self._pose_first_layers()
        return self._point_layers("canonical", self.canonical, layers)

    def _pose_first_layers(self) -> list[nn.Linear]:
        """The pose MLPs' first layers on the point features (geo, rgb)."""
        return [self.geo_offset_net.feat_in, self.rgb_offset_net.feat_in]

    def _point_layers(self, name: str, points: torch.Tensor, layers: list[nn.Linear]) -> list[torch.Tensor]:
        """``layers`` (each 3C -> H_i) on the triplane's features at the constant ``points`` [N, 3] (a buffer;
        ``name`` keys its cached sampling) -> [N, H_i] each. When the points outnumber the texels the layers
        run on the texels and their outputs are sampled (``Triplane.texel_layer``): 3 R^2 x 3C x H plus 12 N H
        multiply-adds instead of N x 3C x H; otherwise on the sampled features."""
        weight, bias = torch.cat([m.weight for m in layers]), torch.cat([m.bias for m in layers])
        sizes = [m.out_features for m in layers]
        tp = self.triplane
        if points.shape[0] <= tp.texels:
            return list(F.linear(tp(points), weight, bias).split(sizes, dim=1))
        sample = self._sparse(f"{name} sampling", (points, tp.center), lambda: tp.sampling(points))
        return list((_SparseProduct.apply(tp.texel_layer(weight), *sample) + bias).split(sizes, dim=1))

    def pose_deltas(self, pose_feat: torch.Tensor, point_layers: list[torch.Tensor] | None = None) -> torch.Tensor:
        """pose_feat [6 J_cond] -> [M, 3 + S + 3] the pose MLPs' deltas (offset, log scale, colour logits) at
        ``pose_points``. point_layers: their first layers' point parts [M, H] x 2 when already computed."""
        if point_layers is None:
            point_layers = self._point_layers("pose", self.pose_points, self._pose_first_layers())
        dgeo = self.geo_offset_net.from_feat_in(point_layers[0], pose_feat)
        return torch.cat([dgeo, self.rgb_offset_net.from_feat_in(point_layers[1], pose_feat)], dim=1)

    def _sparse(self, name: str, sources: tuple[torch.Tensor, ...],
                rows: Callable[[], tuple[torch.Tensor, torch.Tensor, int]]) -> tuple[torch.Tensor, torch.Tensor]:
        """A sparse [N, cols] matrix and its transpose (CSR) kept under ``name``, built from ``rows()`` ->
        (indices [N, K], weights [N, K], cols): row n holds weights[n] at columns indices[n] (repeated columns
        summed). Rebuilt when the buffers in ``sources`` change (a loaded state dict)."""
        key = tuple((t._version, t.data_ptr()) for t in sources)
        cache = self.__dict__.setdefault("_sparse_cache", {})
        if name not in cache or cache[name][0] != key:
            indices, weights, cols = rows()
            n, k = indices.shape
            at = torch.stack([torch.arange(n, device=indices.device).repeat_interleave(k), indices.reshape(-1)])
            coo = torch.sparse_coo_tensor(at, weights.reshape(-1), (n, cols), check_invariants=True)
            with warnings.catch_warnings():  # torch calls its CSR layout beta; sparse.mm on it is the fast path
                warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
                coo = coo.coalesce()
                cache[name] = (key, (coo.to_sparse_csr(), coo.t().coalesce().to_sparse_csr()))
        return cache[name][1]

    def pose_free(self) -> PoseFree:
        """The triplane and the MLPs up to the pose: computed once, it serves ``forward`` at any number of poses
        while the weights do not change (renders without grad: an augmentation snapshot, an evaluation)."""
        z = self._first_layers()
        pose_layers = None
        if self.cfg.pose_dependent:
            pose_layers = z[2:] if not self.coarse_pose else self._point_layers("pose", self.pose_points, self._pose_first_layers())
        return PoseFree(self.geo_net[1:](z[0]), self._with_point_rgb(self.rgb_net[1:](z[1])), pose_layers)

    def forward(self, pose: torch.Tensor, trans: torch.Tensor, pose_free: PoseFree | None = None) -> AvatarOutput:
        """pose: [J, 3], trans: [3] -> world-space Gaussians (plain and refined). pose_free: ``self.pose_free()``
        of the current weights, when already computed."""
        with stage("triplane + MLPs"):
            c = self.pose_free() if pose_free is None else pose_free
            geo = c.geo
            s = 3 if self.cfg.anisotropic else 1
            offset, log_scale = geo[:, :3], geo[:, 3 : 3 + s]
            rgb_logit = c.rgb_logit
            if self.cfg.pose_dependent:
                deltas = self.pose_deltas(self.pose_features(pose), c.pose_layers)
                d_offset, d_log_scale, d_rgb = self.carry_pose_deltas(deltas).split([3, s, 3], dim=1)
            else:
                d_offset = torch.zeros_like(offset)
                d_log_scale = torch.zeros_like(log_scale)
                d_rgb = torch.zeros_like(rgb_logit)
        with stage("posing (LBS)"):
            A = skinning_transforms(self.parents, self.joints, pose[None], trans[None])[0]  # [J, 4, 4]
            skin = self._sparse("skin", (self.skin_indices, self.skin_weights),
                                lambda: (self.skin_indices, self.skin_weights, self.joints.shape[0]))
            T = _SparseProduct.apply(A[:, :3].reshape(-1, 12), *skin).view(-1, 3, 4)  # [N, 3, 4]
            if self.cfg.anisotropic:
                q_local = geo[:, 3 + s :] + torch.tensor([1.0, 0.0, 0.0, 0.0], device=geo.device)
                R_local = quat_to_matrix(q_local)
                quats = matrix_to_quat(T[:, :, :3] @ R_local)
            else:
                quats = torch.zeros(self.num_gaussians, 4, device=geo.device)
                quats[:, 0] = 1.0  # identity: isotropic Gaussians need no rotation
            ones = torch.ones(self.num_gaussians, device=geo.device)

            def gaussians(pos: torch.Tensor, log_s: torch.Tensor, logit: torch.Tensor) -> Gaussians:
                means = apply_transforms(T[None], pos)[0]
                scales = torch.exp((self.base_log_scale + log_s).clamp(-12.0, 2.0)).expand(-1, 3)
                return Gaussians(means, quats, scales, ones, torch.sigmoid(logit))

            plain_pos = self.canonical + offset
            plain = gaussians(plain_pos, log_scale, rgb_logit)
            return AvatarOutput(
                plain=plain,  # without pose dependence the deltas are zeros: the refined set is the plain one
                refined=gaussians(plain_pos + d_offset, log_scale + d_log_scale, rgb_logit + d_rgb)
                if self.cfg.pose_dependent else plain,
                offset=offset,
                log_scale=log_scale,
                delta_offset=d_offset,
                delta_rgb=d_rgb,
            )

    def laplacian(self, values: torch.Tensor) -> torch.Tensor:
        """values: [N, C] -> [N, C], each value minus the mean of its neighbours (their sum: one sparse product)."""
        n, k = self.neighbors.shape
        adjacency = self._sparse("neighbours", (self.neighbors,),
                                 lambda: (self.neighbors, torch.ones(n, k, device=self.neighbors.device), n))
        return values - _SparseProduct.apply(values, *adjacency) / k
