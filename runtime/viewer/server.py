"""The viser server of ``trioman view``: an avatar's splats, its pose controls and playback.

One worker thread poses the avatar (``posing.Poser``: numpy FK + LBS + the pose-dependent ONNX graph)
whenever a control changes or a played frame is due; ``refresh`` does one update. The client keeps the
splats in viser's packed buffer (``GaussianSplatHandle``: per Gaussian 8 uint32, centre 3 x float32,
one word free, covariance upper triangle 6 x float16, RGBA 4 x uint8); an update repacks only the
columns of the arrays that changed (``posing.SplatDiff``) and sends the buffer once, and an update that
changes nothing sends nothing. The server listens on 127.0.0.1 by default; a busy port is an error,
never another port.
"""

from __future__ import annotations

import contextlib
import errno
import io
import ipaddress
import socket
import threading
import time

import numpy as np
import viser

from trioman.runtime.cameras import camera_center, frame_points
from trioman.runtime.viewer.config import ViewerConfig
from trioman.runtime.viewer.posing import MAX_BEND, PoseControls, Poser, SplatDiff

SPLATS = "/avatar"  # the splats' scene node
_FOV_SIZE = 512  # frame_points' image side for the initial camera's field of view


def check_port(host: str, port: int) -> None:
    """Refuse an address this machine does not have (viser would wait forever) and a port another program
    holds (viser would silently take the next one), by binding them once; port 0 checks the address."""
    if not 0 <= port <= 65535:
        raise ValueError(f"port: must lie in [0, 65535], got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as err:
        raise ValueError(f"host: cannot resolve {host!r} ({err.strerror})") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        try:
            s.bind(address)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise ValueError(f"port: {host}:{port} is already in use (another viewer or server); pick another "
                                 f"with `port`, or `port` 0 for any free one") from None
            if err.errno == errno.EADDRNOTAVAIL:
                raise ValueError(f"host: {host} is not an address of this machine; use 127.0.0.1 (this machine "
                                 f"only, the default) or one of its own addresses") from None
            raise ValueError(f"host and port: cannot listen on {host}:{port} ({err.strerror})") from None


def is_local_only(host: str) -> bool:
    """Whether ``host`` is a loopback address (or resolves only to loopback): the viewer is this machine's."""
    try:
        infos = socket.getaddrinfo(host, None)
    except socket.gaierror:
        return False
    return all(ipaddress.ip_address(info[4][0].split("%")[0]).is_loopback for info in infos)


def pack(buffer: np.ndarray, changed: dict[str, np.ndarray]) -> None:
    """Write the changed splat arrays (``posing.Splats`` names) into viser's buffer [N, 8] uint32, in place."""
    if "centers" in changed:
        buffer[:, 0:3] = changed["centers"].view(np.uint32)
    if "covariances" in changed:
        triu = changed["covariances"].reshape(-1, 9)[:, [0, 1, 2, 4, 5, 8]]
        buffer[:, 4:7] = np.ascontiguousarray(triu, dtype=np.float16).view(np.uint32)
    rgba = buffer[:, 7:8].view(np.uint8).reshape(-1, 4)
    for key, cols in (("rgbs", slice(0, 3)), ("opacities", slice(3, 4))):
        if key in changed:
            rgba[:, cols] = np.clip(np.round(changed[key] * 255.0), 0, 255).astype(np.uint8)


def _quiet():
    """viser prints its own banner and a goodbye; the command prints one URL line instead."""
    return contextlib.redirect_stdout(io.StringIO())


class AvatarViewer:
    """A running viewer of ``poser.avatar``. ``stop()`` shuts it down (also on ``with``)."""

    def __init__(self, poser: Poser, config: ViewerConfig | None = None):
        config = config or ViewerConfig()
        check_port(config.host, config.port)
        self.poser = poser
        self.config = config
        self.controls = PoseControls(pose_dependent=poser.avatar.pose_dependent)
        self.diff = SplatDiff()
        self.last_update: dict[str, object] = {}  # ms by stage and the arrays sent (name -> shape)
        self._lock = threading.RLock()
        self._dirty = threading.Event()
        self._stopped = threading.Event()
        self.playing = False
        with _quiet():
            self.server = viser.ViserServer(host=config.host, port=config.port, verbose=False)
        if config.port and self.server.get_port() != config.port:  # taken between the check and the bind
            self.server.stop()
            raise ValueError(f"port: {config.host}:{config.port} is already in use; pick another with `port`")
        self.server.scene.set_up_direction("+z")
        N = poser.avatar.num_gaussians
        self._buffer = np.zeros((N, 8), np.uint32)
        self.splats = self.server.scene.add_gaussian_splats(
            SPLATS, np.zeros((N, 3)), np.zeros((N, 3, 3)), np.zeros((N, 3)), np.zeros((N, 1)))
        self._frame_camera()
        self._build_gui()
        self.refresh()
        self._worker = threading.Thread(target=self._run, name="trioman-view", daemon=True)
        self._worker.start()

    @property
    def url(self) -> str:
        return f"http://{self.config.host}:{self.server.get_port()}"

    # ----------------------------------------------------------------------------------------------
    # posing

    def refresh(self) -> dict[str, np.ndarray]:
        """Pose the avatar under the current controls and send the changed arrays. -> those arrays."""
        with self._lock:
            t0 = time.perf_counter()
            g = self.poser.gaussians(self.controls)
            t1 = time.perf_counter()
            changed = self.diff.update(g)
            if changed:
                pack(self._buffer, changed)
                self.splats.buffer = self._buffer
            t2 = time.perf_counter()
            self.last_update = {"pose_ms": 1000 * (t1 - t0), "send_ms": 1000 * (t2 - t1),
                                "arrays": {k: tuple(v.shape) for k, v in changed.items()}}
            self._show_stats()
            return changed

    def time_updates(self, updates: int) -> dict[str, float]:
        """Time ``updates`` pose updates over the motion's frames (a played clip). -> median ms: posing (FK + LBS
        + the pose-dependent graph), packing (the changed arrays into the buffer, queued to the clients), total."""
        if updates < 1:
            raise ValueError(f"updates: must be >= 1, got {updates}")
        pose, send = [], []
        frames = self.poser.motion.num_frames
        for k in range(updates):
            self.controls.frame = (self.controls.frame + 1) % frames if frames > 1 else 0
            self.controls.bends = {} if frames > 1 else {"root": float(k % 2)}  # a one-frame motion: turn instead
            self.refresh()
            pose.append(self.last_update["pose_ms"])
            send.append(self.last_update["send_ms"])
        p, q = float(np.median(pose)), float(np.median(send))
        return {"pose_ms": p, "send_ms": q, "total_ms": float(np.median(np.add(pose, send)))}

    def _run(self) -> None:
        """The worker: refresh when a control changed; while playing, advance one frame per period."""
        next_at = time.perf_counter()
        while not self._stopped.is_set():
            if self.playing:
                period = 1.0 / (self.config.fps or self.poser.motion.fps)
                self._dirty.wait(max(0.0, next_at - time.perf_counter()))
                if time.perf_counter() >= next_at and self.playing and not self.controls.rest:
                    with self._lock:
                        self.controls.frame = (self.controls.frame + 1) % self.poser.motion.num_frames
                        self._frame_slider.value = self.controls.frame
                    next_at = time.perf_counter() + period
                    self._dirty.set()
            else:
                self._dirty.wait(0.25)
                next_at = time.perf_counter()
            if self._dirty.is_set() and not self._stopped.is_set():
                self._dirty.clear()
                self.refresh()

    def _changed(self) -> None:
        self._dirty.set()

    # ----------------------------------------------------------------------------------------------
    # scene and controls

    def _frame_camera(self) -> None:
        """The first view: the rest pose framed as ``trioman render --camera AZ,EL`` frames it."""
        J = self.poser.avatar.skeleton.num_joints
        g = self.poser.avatar.gaussians(np.zeros((J, 3)), np.zeros(3), pose_dependent=False)
        K, viewmat, center = frame_points(g.means, (_FOV_SIZE, _FOV_SIZE), np.deg2rad(self.config.azimuth),
                                          np.deg2rad(self.config.elevation))
        cam = self.server.initial_camera
        cam.fov = float(2 * np.arctan(0.5 * _FOV_SIZE / K[1, 1]))
        cam.up = (0.0, 0.0, 1.0)
        cam.look_at = tuple(center)
        cam.position = tuple(camera_center(viewmat))

    def _build_gui(self) -> None:
        gui, poser = self.server.gui, self.poser
        with gui.add_folder("Motion"):
            self._motion = gui.add_dropdown("motion", tuple(poser.catalog), initial_value=poser.name)
            self._play = gui.add_button("Play")
            self._frame_slider = gui.add_slider("frame", 0, max(1, poser.motion.num_frames - 1), 1, 0)
        with gui.add_folder("Pose"):
            self._rest = gui.add_checkbox("rest pose", False)
            self._pose_dep = gui.add_checkbox("pose-dependent", self.controls.pose_dependent,
                                              disabled=not poser.avatar.pose_dependent,
                                              hint=None if poser.avatar.pose_dependent else "this avatar has none")
            self._bends = {g: gui.add_slider(f"bend {g}", -MAX_BEND, MAX_BEND, 1.0, 0.0) for g in poser.bend_groups}
            reset = gui.add_button("Reset bends")
        self._stats = gui.add_markdown("")

        @self._motion.on_update
        def _(_event) -> None:
            with self._lock:
                motion = poser.select(self._motion.value)
                self.controls.frame = 0
                self._frame_slider.max = max(1, motion.num_frames - 1)
                self._frame_slider.value = 0
            self._changed()

        @self._play.on_click
        def _(_event) -> None:
            self.playing = not self.playing
            self._play.label = "Pause" if self.playing else "Play"
            self._changed()

        @self._frame_slider.on_update
        def _(_event) -> None:
            value = int(self._frame_slider.value)
            if value != self.controls.frame and value < poser.motion.num_frames:
                self.controls.frame = value
                self._changed()

        @self._rest.on_update
        def _(_event) -> None:
            self.controls.rest = bool(self._rest.value)
            self._changed()

        @self._pose_dep.on_update
        def _(_event) -> None:
            self.controls.pose_dependent = bool(self._pose_dep.value)
            self._changed()

        for group, slider in self._bends.items():
            def on_bend(_event, group=group, slider=slider) -> None:
                self.controls.bends = {**self.controls.bends, group: float(slider.value)}
                self._changed()

            slider.on_update(on_bend)

        @reset.on_click
        def _(_event) -> None:
            for slider in self._bends.values():
                slider.value = 0.0
            self.controls.bends = {}
            self._changed()

    def _show_stats(self) -> None:
        u = self.last_update
        sent = ", ".join(f"{k} {list(s)}" for k, s in u["arrays"].items()) or "nothing (unchanged)"
        self._stats.content = (f"**{self.poser.avatar.num_gaussians:,} Gaussians**; last update "
                               f"{u['pose_ms']:.1f} ms posing + {u['send_ms']:.1f} ms packing; sent: {sent}")

    # ----------------------------------------------------------------------------------------------

    def stop(self) -> None:
        """Stop the worker and the server (idempotent)."""
        if self._stopped.is_set():
            return
        self._stopped.set()
        self._dirty.set()
        self._worker.join(timeout=5.0)
        with _quiet():
            self.server.stop()

    def __enter__(self) -> "AvatarViewer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
