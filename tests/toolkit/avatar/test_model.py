"""The Gaussian avatar: placement by LBS against the numpy reference, shapes, extremes, options."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.runtime.factories import random_mesh  # noqa: E402
from tests.toolkit.avatar.factories import SMALL, grid_mesh  # noqa: E402
from trioman.runtime.skeleton import SkinnedMesh  # noqa: E402
from trioman.toolkit.avatar.mesh_ops import avatar_points, level_interpolation, subdivide  # noqa: E402
from trioman.toolkit.avatar.model import AvatarConfig, GaussianAvatar  # noqa: E402


def test_gaussians_follow_the_numpy_lbs_at_zero_offsets():
    mesh = random_mesh(2, J=6, V=60)
    model = GaussianAvatar(mesh, AvatarConfig(**SMALL))
    rng = np.random.default_rng(0)
    pose, trans = rng.normal(size=(6, 3)), rng.normal(size=3)
    out = model(torch.from_numpy(pose).float(), torch.from_numpy(trans).float())
    # The offset heads start at zero, so Gaussians sit on the posed vertices.
    np.testing.assert_allclose(out.refined.means.detach().numpy(), mesh.pose(pose, trans), atol=1e-5)
    np.testing.assert_allclose(out.plain.means.detach().numpy(), mesh.pose(pose, trans), atol=1e-5)


def test_attribute_shapes_and_ranges():
    mesh = grid_mesh()
    model = GaussianAvatar(mesh, AvatarConfig(**SMALL))
    out = model(torch.zeros(4, 3), torch.zeros(3))
    N = mesh.num_vertices
    for g in (out.plain, out.refined):
        assert g.means.shape == (N, 3) and g.quats.shape == (N, 4) and g.scales.shape == (N, 3)
        assert torch.all(g.opacities == 1) and torch.all((g.colors > 0) & (g.colors < 1))
        assert torch.all(g.scales > 0) and torch.all(g.scales[:, 0] == g.scales[:, 1])  # isotropic


def test_anisotropic_and_no_pose_dependence():
    mesh = grid_mesh()
    aniso = GaussianAvatar(mesh, AvatarConfig(anisotropic=True, **SMALL))
    out = aniso(torch.full((4, 3), 0.3), torch.zeros(3))
    np.testing.assert_allclose(out.refined.quats.norm(dim=-1).detach().numpy(), 1.0, atol=1e-6)
    plain = GaussianAvatar(mesh, AvatarConfig(pose_dependent=False, **SMALL))
    out = plain(torch.full((4, 3), 0.3), torch.zeros(3))
    assert torch.equal(out.plain.means, out.refined.means) and torch.equal(out.plain.colors, out.refined.colors)
    assert not hasattr(plain, "geo_offset_net")


@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi - 1e-6, 50.0])
def test_extreme_poses_give_finite_gaussians_and_gradients(angle):
    mesh = grid_mesh()
    model = GaussianAvatar(mesh, AvatarConfig(**SMALL))
    pose = torch.full((4, 3), angle / np.sqrt(3), requires_grad=True)
    out = model(pose, torch.tensor([1e3, -1e3, 0.0]))
    loss = sum(t.sum() for t in (*out.refined[:3], out.refined.colors))
    loss.backward()
    assert all(torch.isfinite(t).all() for t in out.refined)
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_subdivision_and_subsampling():
    mesh = grid_mesh()
    verts, faces, source = subdivide(mesh.vertices, mesh.faces)
    E = len(np.unique(np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]]), 1), axis=0))
    assert len(verts) == mesh.num_vertices + E and len(faces) == 4 * len(mesh.faces)
    # Each midpoint lies halfway along the edge to its skinning source.
    mids = np.arange(mesh.num_vertices, len(verts))
    assert np.all(np.linalg.norm(verts[mids] - mesh.vertices[source[mids]], axis=1) > 0)
    pts, idx, w = avatar_points(mesh, subdivisions=1, keep=0.5, seed=1)
    assert len(pts) == round(0.5 * len(verts)) and idx.shape == (len(pts), 2)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    with pytest.raises(ValueError, match="keep"):
        avatar_points(mesh, keep=0.0)


def _by_hand_carry(mesh: SkinnedMesh, level: int, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """The level's vertices [M, 3] and the dense map [N, M] to the subdivided mesh's vertices, by hand: each
    midpoint step appends, per edge (in ``subdivide``'s order), the mean of its two ends' rows."""
    verts, faces = mesh.vertices, mesh.faces
    for _ in range(level):
        verts, faces, _ = subdivide(verts, faces)
    rows = np.eye(len(verts))
    coarse = verts
    for _ in range(subdivisions - level):
        sides = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        edges = np.unique(np.sort(sides, axis=1), axis=0)
        rows = np.concatenate([rows, 0.5 * (rows[edges[:, 0]] + rows[edges[:, 1]])])
        verts, faces, _ = subdivide(verts, faces)
        np.testing.assert_allclose(rows @ coarse, verts, atol=1e-12)  # the map makes the subdivided points
    return coarse, rows


@pytest.mark.parametrize("level,subdivisions", [(0, 1), (0, 2), (1, 2), (2, 2)])
def test_level_interpolation_makes_the_subdivided_points(level, subdivisions):
    mesh = grid_mesh()
    coarse, dense = _by_hand_carry(mesh, level, subdivisions)
    for keep in (1.0, 0.4):
        pts, idx, w = level_interpolation(mesh, level, subdivisions, keep, seed=2)
        fine = avatar_points(mesh, subdivisions, keep, seed=2)[0]
        np.testing.assert_array_equal(pts, coarse)
        np.testing.assert_allclose((w[..., None] * pts[idx]).sum(1), fine, atol=1e-12)
        assert np.all(w >= 0) and np.all(w.sum(1) == 1) and idx.shape[1] <= 2 ** (subdivisions - level)
        if keep == 1.0:
            got = np.zeros_like(dense)
            np.add.at(got, (np.arange(len(idx))[:, None], idx), w)
            np.testing.assert_array_equal(got, dense)  # exactly the subdivision's dyadic weights
    with pytest.raises(ValueError, match=r"level: must lie in \[0, subdivisions = 1\], got 2"):
        level_interpolation(mesh, 2, 1)


def _perturbed(model: GaussianAvatar, seed: int = 0) -> GaussianAvatar:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():  # non-zero output layers, so the deltas are not zeros
        for prm in model.parameters():
            prm.add_(0.1 * torch.randn(prm.shape, generator=gen))
    return model


@pytest.mark.parametrize("level,subdivisions,anisotropic", [(0, 1, False), (0, 2, False), (1, 2, True)])
def test_coarse_pose_mlps_match_the_brute_force_reference(level, subdivisions, anisotropic):
    """pose_subdivisions: the pose MLPs at the coarse level's vertices (triplane sampled there), their deltas
    averaged up by hand, subdivision by subdivision: the same deltas and the same gradients."""
    mesh = grid_mesh()
    cfg = AvatarConfig(subdivisions=subdivisions, pose_subdivisions=level, anisotropic=anisotropic, **SMALL)
    model = _perturbed(GaussianAvatar(mesh, cfg))
    coarse, dense = _by_hand_carry(mesh, level, subdivisions)
    assert model.pose_points.shape == (len(coarse), 3) and model.num_gaussians == len(dense)
    pose = torch.full((4, 3), 0.3)
    results = []
    for fast in (True, False):
        model.zero_grad()
        if fast:
            out = model(pose, torch.zeros(3))
            d_off, d_rgb = out.delta_offset, out.delta_rgb
            d_ls = torch.log(out.refined.scales[:, 0]) - torch.log(out.plain.scales[:, 0])
        else:
            feats = model.triplane(torch.from_numpy(coarse).float())
            pf = model.pose_features(pose)
            P = torch.from_numpy(dense).float()
            dgeo, d_rgb = P @ model.geo_offset_net(feats, pf), P @ model.rgb_offset_net(feats, pf)
            d_off, d_ls = dgeo[:, :3], dgeo[:, 3]
        (d_off.square().sum() + d_ls.sum() + d_rgb.sin().sum()).backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters() if "offset_net" in n or "triplane" in n}
        results.append(((d_off, d_ls, d_rgb), grads))
    (got, grads_f), (want, grads_r) = results
    assert float(want[0].detach().abs().max()) > 1e-2 and float(want[2].detach().abs().max()) > 1e-2
    for a, b, name in zip(got, want, ("d_offset", "d_log_scale", "d_rgb")):
        torch.testing.assert_close(a.detach(), b.detach(), atol=1e-5, rtol=0, msg=name)
    for name in grads_r:
        scale = max(1.0, float(grads_r[name].abs().max()))
        torch.testing.assert_close(grads_f[name], grads_r[name], atol=1e-5 * scale, rtol=0, msg=name)


@pytest.mark.parametrize("options", [dict(pose_dependent=False), dict(), dict(anisotropic=True),
                                     dict(subdivisions=1, pose_subdivisions=0)])
def test_pose_free_part_computed_once_serves_every_pose(options):
    """forward(pose, trans, model.pose_free()) gives what forward(pose, trans) gives, bit for bit, at poses and
    translations drawn anew for each call."""
    mesh = grid_mesh()
    model = _perturbed(GaussianAvatar(mesh, AvatarConfig(**SMALL, **options)))
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        pose_free = model.pose_free()
        for _ in range(3):
            pose, trans = torch.randn(4, 3, generator=gen), torch.randn(3, generator=gen)
            got, want = model(pose, trans, pose_free), model(pose, trans)
            for a, b in zip(got.plain + got.refined + got[2:], want.plain + want.refined + want[2:]):
                assert torch.equal(a, b)
    assert float((got.delta_offset.abs().max())) > 0 or not model.cfg.pose_dependent


def test_pose_subdivisions_option():
    """Checked; not in the state dict (derived from the mesh); old configs (without the field) keep the
    pose MLPs at the Gaussians; the full preset runs them on the body mesh's own vertices."""
    import dataclasses

    from trioman.toolkit.train.config import TrainConfig, preset

    for bad in (2, -1, True, 0.0):
        with pytest.raises(ValueError, match=rf"pose_subdivisions: must be None or an integer in \[0, subdivisions = 1\], got {bad!r}"):
            AvatarConfig(subdivisions=1, pose_subdivisions=bad)
    mesh = grid_mesh()
    at_gaussians = GaussianAvatar(mesh, AvatarConfig(subdivisions=1, **SMALL))
    coarse = GaussianAvatar(mesh, AvatarConfig(subdivisions=1, pose_subdivisions=0, **SMALL))
    assert not at_gaussians.coarse_pose and coarse.coarse_pose
    assert at_gaussians.pose_points is at_gaussians.canonical and coarse.pose_points.shape == (mesh.num_vertices, 3)
    assert at_gaussians.state_dict().keys() == coarse.state_dict().keys()
    old = preset("full").to_dict()
    del old["avatar"]["pose_subdivisions"]
    assert TrainConfig.from_dict(old).avatar.pose_subdivisions is None
    assert preset("full").avatar.pose_subdivisions == 0 and preset("quick").avatar.pose_subdivisions is None
    assert dataclasses.replace(preset("full").avatar, pose_subdivisions=None) == TrainConfig.from_dict(old).avatar


def test_laplacian_of_constant_is_zero():
    model = GaussianAvatar(grid_mesh(), AvatarConfig(**SMALL))
    assert torch.allclose(model.laplacian(torch.ones(model.num_gaussians, 3)), torch.zeros(1))


def test_same_seed_same_initial_weights_and_global_rng_untouched():
    torch.manual_seed(123)
    before = torch.rand(3)
    torch.manual_seed(123)
    a = GaussianAvatar(grid_mesh(), AvatarConfig(seed=4, **SMALL))
    assert torch.equal(torch.rand(3), before), "model construction must not consume the global RNG"
    b = GaussianAvatar(grid_mesh(), AvatarConfig(seed=4, **SMALL))
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(va, vb), k


def _reference_forward(model: GaussianAvatar, pose: torch.Tensor, trans: torch.Tensor):
    """The avatar's forward pass as written before issue 27 (grid_sample's [N, 3C] copy, one first layer per
    MLP, LBS by gathering the joints' transforms, both sets computed): the oracle of the faster one. The test
    computes the Laplacian the old way (a gather and a mean) beside it."""
    import torch.nn.functional as F

    from trioman.toolkit.avatar.model import Gaussians
    from trioman.toolkit.body.skinning import apply_transforms, blend_transforms, skinning_transforms
    from trioman.toolkit.rotations import matrix_to_quat, quat_to_matrix

    tp = model.triplane
    p = ((model.canonical - tp.center) / tp.half_size).clamp(-1, 1)
    coords = torch.stack([p[:, [0, 1]], p[:, [0, 2]], p[:, [1, 2]]])
    feats = F.grid_sample(tp.planes, coords[:, :, None, :], mode="bilinear", align_corners=True)
    feats = feats[..., 0].permute(2, 0, 1).reshape(p.shape[0], -1)
    cfg, s = model.cfg, 3 if model.cfg.anisotropic else 1
    geo = model.geo_net(feats)
    offset, log_scale = geo[:, :3], geo[:, 3:3 + s]
    logit = model.rgb_logits(feats)
    d_off, d_ls, d_rgb = torch.zeros_like(offset), torch.zeros_like(log_scale), torch.zeros_like(logit)
    if cfg.pose_dependent:
        pf = model.pose_features(pose)
        dgeo = model.geo_offset_net(feats, pf)
        d_off, d_ls, d_rgb = dgeo[:, :3], dgeo[:, 3:3 + s], model.rgb_offset_net(feats, pf)
    A = skinning_transforms(model.parents, model.joints, pose[None], trans[None])
    T = blend_transforms(A, model.skin_indices, model.skin_weights)[0]
    n = model.num_gaussians
    if cfg.anisotropic:
        quats = matrix_to_quat(T[:, :, :3] @ quat_to_matrix(geo[:, 3 + s:] + torch.tensor([1.0, 0.0, 0.0, 0.0])))
    else:
        quats = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4)

    def gaussians(pos, log_s, lg):
        scales = torch.exp((model.base_log_scale + log_s).clamp(-12.0, 2.0)).expand(-1, 3)
        return Gaussians(apply_transforms(T[None], pos)[0], quats, scales, torch.ones(n), torch.sigmoid(lg))

    pos = model.canonical + offset
    return (gaussians(pos, log_scale, logit), gaussians(pos + d_off, log_scale + d_ls, logit + d_rgb),
            offset, log_scale)


@pytest.mark.parametrize("options", [dict(pose_dependent=False, point_colors=True),
                                     dict(anisotropic=True, subdivisions=1)])
def test_training_step_matches_the_reference_step(options):
    """One training step (forward, render of both sets, loss with the Laplacians, gradients, Adam update) with the avatar's and the
    rasterizer's fast paths against the reference forward and the rasterizer at 8 px tiles: within 1e-5."""
    from trioman.toolkit.render import rasterize

    mesh = grid_mesh()
    torch.manual_seed(0)
    models = [GaussianAvatar(mesh, AvatarConfig(**SMALL, **options)) for _ in range(2)]
    with torch.no_grad():  # non-zero heads, so every path carries a gradient
        for prm in models[0].parameters():
            prm.add_(0.05 * torch.randn_like(prm))
    models[1].load_state_dict(models[0].state_dict())
    pose, trans = torch.full((4, 3), 0.2), torch.tensor([0.0, 0.0, 0.1])
    K = torch.tensor([[40.0, 0, 24], [0, 40.0, 24], [0, 0, 1]])
    viewmat = torch.eye(4)
    viewmat[2, 3] = 1.5
    target = torch.rand(48, 48, 3, generator=torch.Generator().manual_seed(1))
    results = []
    for model, fast in zip(models, (True, False)):
        pose = pose.detach().requires_grad_(True)  # the LBS's gradient too
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        if fast:
            out = model(pose, trans)
            sets, offset, log_scale = (out.plain, out.refined), out.offset, out.log_scale
            lap = model.laplacian(offset), model.laplacian(log_scale)
        else:
            plain, refined, offset, log_scale = _reference_forward(model, pose, trans)
            sets = plain, refined
            lap = tuple(v - v[model.neighbors].mean(1) for v in (offset, log_scale))
        reg = offset.square().mean() + log_scale.square().mean() + 100 * sum(x.square().mean() for x in lap)
        loss = reg
        for g in sets:
            img = rasterize(*g, viewmat, K, 48, 48, background=torch.ones(3), **({} if fast else {"tile_size": 8, "backend": "torch"})).rgb
            loss = loss + (img - target).abs().mean()
        loss.backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters()} | {"pose": pose.grad.clone()}
        optimizer.step()
        results.append((loss.detach(), [g.means.detach() for g in sets], grads, dict(model.named_parameters())))
    (loss_f, means_f, grads_f, params_f), (loss_r, means_r, grads_r, params_r) = results
    assert abs(float(loss_f - loss_r)) < 1e-5
    for a, b in zip(means_f, means_r):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    for name in grads_r:
        scale = max(1.0, float(grads_r[name].abs().max()))
        torch.testing.assert_close(grads_f[name], grads_r[name], atol=1e-5 * scale, rtol=0, msg=name)
        if name != "pose":
            torch.testing.assert_close(params_f[name].detach(), params_r[name].detach(), atol=1e-5, rtol=0, msg=name)
    assert float(grads_r["pose"].abs().max()) > 1e-3
