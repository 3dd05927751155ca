"""Pinhole cameras in the OpenCV convention (x right, y down, z forward), z-up world.

``viewmat`` is world->camera [4, 4]; ``K`` is [3, 3] in pixels with pixel centres at (j + 0.5, i + 0.5).
Orbit angles: azimuth 0 puts the camera in front of a subject facing -y, azimuth +90 deg on the
subject's left (+x); elevation > 0 looks down from above.
"""

from __future__ import annotations

import numpy as np


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """[3, 3] pinhole matrix."""
    if not (fx > 0 and fy > 0):
        raise ValueError(f"K: focal lengths must be > 0, got fx={fx}, fy={fy}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """World->camera [4, 4] for a camera at ``eye`` looking at ``target`` with world ``up`` on screen up."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    if not (np.all(np.isfinite(eye)) and np.all(np.isfinite(target))):
        raise ValueError(f"eye: camera position {eye.tolist()} or target {target.tolist()} is not finite")
    forward = target - eye
    n = np.linalg.norm(forward)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"eye: camera position {eye.tolist()} coincides with target {target.tolist()}")
    forward /= n
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight along up: pick any perpendicular
        right = np.cross(forward, [1.0, 0.0, 0.0] if abs(forward[0]) < 0.9 else [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    viewmat = np.eye(4)
    viewmat[:3, :3] = R
    viewmat[:3, 3] = -R @ eye
    return viewmat


def orbit_position(center: np.ndarray, azimuth: float, elevation: float, distance: float) -> np.ndarray:
    """Camera centre on a sphere about ``center`` (angles in radians, see module doc). -> [3]."""
    if not distance > 0:
        raise ValueError(f"distance: must be > 0, got {distance}")
    ce = np.cos(elevation)
    offset = np.array([ce * np.sin(azimuth), -ce * np.cos(azimuth), np.sin(elevation)])
    return np.asarray(center, dtype=np.float64) + distance * offset


def orbit_viewmat(center: np.ndarray, azimuth: float, elevation: float, distance: float) -> np.ndarray:
    """World->camera [4, 4] looking at ``center`` from the given orbit angles."""
    return look_at(orbit_position(center, azimuth, elevation, distance), center)


def camera_center(viewmat: np.ndarray) -> np.ndarray:
    """Camera position in world coordinates. [..., 4, 4] -> [..., 3]."""
    R, t = viewmat[..., :3, :3], viewmat[..., :3, 3]
    return -np.einsum("...ba,...b->...a", R, t)


def project(points: np.ndarray, viewmat: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 3] -> pixel coordinates [N, 2] and camera depth [N]."""
    cam = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam[:, :2] / z[:, None]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    return uv, z


_MAX_FAR = 1e4  # frame_points: the farthest a subject may lie from the origin, in units of its radius


def frame_points(points: np.ndarray, size: tuple[int, int], azimuth: float, elevation: float,
                 fill: float = 0.85, margin: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A camera that keeps the bulk of ``points`` [N, 3] in view from any orbit angle (radians): it looks
    at the centre of their bounding box from a distance of 3 bounding-sphere radii (``margin`` m added),
    with the focal length that makes the sphere span ``fill`` of the shorter image side. The bulk is every
    point within twice the 99th-percentile or five times the median distance from the median point, whichever
    is less (``margin`` added), so a few far outliers (a stray Gaussian at 100 m) do not shrink the rest to a dot. Points too far from the origin
    for their extent to survive float32 rendering are a ValueError.
    size: (width, height). -> (K [3, 3], viewmat [4, 4], center [3])."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0 or not np.all(np.isfinite(points)):
        raise ValueError(f"points: need finite points to frame, got {len(points)} point(s)")
    if not 0 < fill <= 1:
        raise ValueError(f"fill: must lie in (0, 1], got {fill}")
    width, height = size
    d = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    bulk = points[d <= min(2.0 * np.percentile(d, 99), 5.0 * np.median(d)) + margin]
    center = 0.5 * (bulk.min(0) + bulk.max(0))
    radius = float(np.linalg.norm(bulk - center, axis=1).max()) + margin
    far = float(np.abs(center).max())
    if far > _MAX_FAR * radius:
        raise ValueError(f"points: {far:.3g} m from the origin, too far for their {radius:.3g} m extent to render "
                         f"(float32 keeps about 7 digits)")
    distance = 3.0 * radius
    half = np.tan(np.arcsin(radius / distance))  # tangent of the sphere's angular radius
    f = 0.5 * fill * min(width, height) / half
    K = intrinsics(f, f, width / 2, height / 2)
    return K, orbit_viewmat(center, azimuth, elevation, distance), center
