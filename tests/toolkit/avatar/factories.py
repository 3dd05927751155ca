"""Inputs of the Gaussian avatar's tests, built without torch: a small avatar configuration and a small skinned
icosphere."""

import numpy as np

from trioman.runtime.skeleton import Skeleton, SkinnedMesh

SMALL = dict(triplane_channels=4, triplane_res=8, hidden=16, knn=3)


def grid_mesh(J: int = 4) -> SkinnedMesh:
    """A small closed-ish surface (an icosphere) skinned to a chain of joints along z."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    verts = np.asarray(sphere.vertices)
    names = ("root", "spine01", "neck01", "head")[:J]
    joints = np.stack([np.zeros(J), np.zeros(J), np.linspace(-0.3, 0.3, J)], 1)
    sk = Skeleton(names, np.arange(-1, J - 1), joints)
    near = np.argsort(np.abs(verts[:, 2:3] - joints[None, :, 2]), axis=1)[:, :2]
    w = np.array([0.7, 0.3], np.float32)
    return SkinnedMesh(sk, verts, np.asarray(sphere.faces), near, np.tile(w, (len(verts), 1)))
