"""``trioman view`` in a real browser: headless chromium (software WebGL) opens the page, the splats
appear where the client's camera puts the avatar, before and after a pose change.

Without the viewer's splats the page is the baseline; a pixel is the avatar's when it differs from the
baseline. The test waits until the avatar's pixels settle, then checks that they lie inside the box the
posed Gaussian centres project to through the client's own camera (a margin for the splats' extent),
cover a good part of it and, for the test's avatar, stand upright (red at the bottom, blue at the top). The screenshot goes to $TRIOMAN_VIEWER_SCREENSHOT (the README's
docs/images/viewer.png is made so, with $TRIOMAN_VIEWER_AVATAR naming a trained avatar) or the
test's temporary folder.
Needs chromium and chromium-driver (Debian packages; .ci/run installs them) and selenium (the dev extra).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer needs viser: pip install 'trioman[viewer]'")
webdriver = pytest.importorskip("selenium.webdriver", reason="the browser test drives chromium with selenium (the dev extra)")

from tests.runtime.viewer.helpers import make_avatar  # noqa: E402
from trioman.runtime.rotations import quat_to_matrix  # noqa: E402
from trioman.runtime.viewer.app import open_viewer  # noqa: E402

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(CHROMIUM is None or CHROMEDRIVER is None,
                                reason="headless chromium missing: apt-get install chromium chromium-driver")

WINDOW = (1100, 700)
CHANGED = 40  # a pixel is the avatar's when a channel differs from the baseline by more (of 255)
TIMEOUT = 120.0  # seconds for the splats to appear or move (software WebGL on a busy CPU)
# Software WebGL: SwiftShader through ANGLE; no GPU, no sandbox (CI runs as root).
FLAGS = ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-gl=angle", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--hide-scrollbars", f"--window-size={WINDOW[0]},{WINDOW[1]}")


@pytest.fixture
def browser():
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    yield driver
    driver.quit()


# The control panel's box: the widest ancestor of its "Connected" label narrower than 60 % of the window.
PANEL_JS = """
const label = [...document.querySelectorAll('*')].find(e => e.childElementCount === 0 && e.textContent.trim() === 'Connected');
let e = label;
while (e.parentElement && e.parentElement.getBoundingClientRect().width < 0.6 * window.innerWidth) e = e.parentElement;
const r = e.getBoundingClientRect();
return [r.left, r.top, r.right, r.bottom];
"""


def screenshot(driver) -> np.ndarray:
    """The page as RGB uint8 [H, W, 3], without viser's notifications (the software-WebGL warning)."""
    import cv2

    driver.execute_script("document.querySelectorAll('[class*=Notification-root]').forEach(e => e.style.display = 'none')")
    png = np.frombuffer(driver.get_screenshot_as_png(), np.uint8)
    return cv2.cvtColor(cv2.imdecode(png, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def scene_mask(driver, shape: tuple[int, int]) -> np.ndarray:
    """[H, W] bool: the pixels of the 3D view, the control panel (its sliders and text change) left out."""
    x0, y0, x1, y1 = (int(round(v)) for v in driver.execute_script(PANEL_JS))
    keep = np.ones(shape, bool)
    keep[max(0, y0 - 2):y1 + 2, max(0, x0 - 2):x1 + 2] = False
    return keep


def expected_box(viewer, canvas: dict) -> np.ndarray:
    """[x0, y0, x1, y1] page pixels of the posed splats through the client's camera (OpenCV axes, vertical fov),
    each splat reaching 3 sigma of its largest scale."""
    (client,) = viewer.server.get_clients().values()
    cam = client.camera
    R = quat_to_matrix(np.asarray(cam.wxyz, dtype=np.float64))  # camera -> world
    g = viewer.poser.gaussians(viewer.controls)
    p = (g.means.astype(np.float64) - cam.position) @ R  # world -> camera
    f = 0.5 * canvas["height"] / np.tan(0.5 * cam.fov)
    u = f * p[:, 0] / p[:, 2] + 0.5 * canvas["width"] + canvas["x"]
    v = f * p[:, 1] / p[:, 2] + 0.5 * canvas["height"] + canvas["y"]
    r = 3.0 * f * g.scales.max(1) / p[:, 2]
    return np.array([(u - r).min(), (v - r).min(), (u + r).max(), (v + r).max()])


def avatar_pixels(driver, baseline: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
    """Wait until the avatar's pixels (against the baseline) appear, differ from ``previous`` and settle.
    -> [H, W] bool."""
    start, last = time.perf_counter(), None
    scene = scene_mask(driver, baseline.shape[:2])
    while time.perf_counter() - start < TIMEOUT:
        mask = (np.abs(screenshot(driver).astype(int) - baseline).max(-1) > CHANGED) & scene
        moved = previous is None or (mask != previous).sum() > 0.1 * max(previous.sum(), 1)
        if mask.sum() > 200 and moved and last is not None and (mask != last).sum() < 0.005 * mask.sum():
            return mask
        last = mask
        time.sleep(1.0)
    pytest.fail(f"the splats did not appear or settle within {TIMEOUT:.0f} s ({0 if last is None else int(last.sum())} "
                f"changed pixels)")


def check_inside(mask: np.ndarray, box: np.ndarray) -> None:
    """The avatar's pixels lie inside the projected box and fill a good part of it."""
    x0, y0, x1, y1 = box
    margin = 4  # pixels: rounding, antialiasing
    ys, xs = np.nonzero(mask)
    inside = (xs >= x0 - margin) & (xs <= x1 + margin) & (ys >= y0 - margin) & (ys <= y1 + margin)
    assert inside.mean() > 0.98, (f"{int((~inside).sum())} of {len(xs)} avatar pixels outside the box {box.round()} "
                                  f"(+{margin:.0f} px): x {xs.min()}..{xs.max()}, y {ys.min()}..{ys.max()}")
    area = (x1 - x0) * (y1 - y0)
    assert len(xs) > 0.15 * area, f"{len(xs)} avatar pixels in a box of {area:.0f} px^2"


def check_upright(image: np.ndarray, mask: np.ndarray) -> None:
    """The test avatar (helpers.make_avatar) is red at the bottom and blue at the top; upside down, they swap."""
    ys, xs = np.nonzero(mask)
    rgb, mid = image[ys, xs].astype(float), np.median(ys)
    top, bottom = rgb[ys < mid].mean(0), rgb[ys > mid].mean(0)  # page rows grow downwards
    assert top[2] > top[0] and bottom[0] > bottom[2], f"mean RGB of the upper half {top.round()}, lower half {bottom.round()}"


def test_the_splats_show_where_the_camera_puts_them_before_and_after_a_pose_change(browser, tmp_path):
    avatar = os.environ.get("TRIOMAN_VIEWER_AVATAR")
    ours = avatar is None
    if avatar is None:
        make_avatar(tmp_path / "avatar", n=1500)
        avatar = tmp_path / "avatar"
    shot = Path(os.environ.get("TRIOMAN_VIEWER_SCREENSHOT", tmp_path / "viewer.png"))
    viewer = open_viewer(avatar, port=0)
    try:
        viewer.splats.visible = False
        browser.get(viewer.url)
        start = time.perf_counter()
        while not viewer.server.get_clients() and time.perf_counter() - start < 30:
            time.sleep(0.2)
        time.sleep(3.0)  # the client draws its first frames
        baseline = screenshot(browser).astype(int)
        canvas = browser.execute_script(
            "const r = [...document.querySelectorAll('canvas')].sort((a, b) => b.clientWidth * b.clientHeight - "
            "a.clientWidth * a.clientHeight)[0].getBoundingClientRect(); return {x: r.x, y: r.y, width: r.width, "
            "height: r.height}")
        assert canvas["width"] > 0.5 * WINDOW[0], canvas

        viewer.splats.visible = True
        before = avatar_pixels(browser, baseline)
        check_inside(before, expected_box(viewer, canvas))
        if ours:
            check_upright(screenshot(browser), before)

        group = "arms" if "arms" in viewer.poser.bend_groups else viewer.poser.bend_groups[-1]
        viewer._bends[group].value = -70.0 if group == "arms" else 80.0  # as a user moves the slider
        after = avatar_pixels(browser, baseline, previous=before)
        assert viewer.controls.bends == {group: viewer._bends[group].value}
        check_inside(after, expected_box(viewer, canvas))

        shot.parent.mkdir(parents=True, exist_ok=True)
        import cv2

        assert cv2.imwrite(str(shot), cv2.cvtColor(screenshot(browser), cv2.COLOR_RGB2BGR))
    finally:
        viewer.stop()
