"""What ``trioman eval`` measures (toolkit/evaluate.py), each setting with its option (runtime/options.py): the
library's defaults and the command's are these fields. Standard-library imports only: the command builds its
parser from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, option

PROTOCOLS = ("ours", "exavatar")
# evaluate(poses=...): the run's corrected poses, the subject's stored, the truth, or the run's refitted to each
# frame's own pixels (toolkit/pose_refit.py)
POSES = ("run", "stored", "true", "optimised")
REFIT_STEPS = 200  # most L-BFGS iterations a frame of the "optimised" refit (toolkit/pose_refit.py, RefitSettings)


@dataclass(frozen=True)
class EvalOptions:
    split: str = option("test", choices=("train", "test"), help="frames to evaluate")
    protocol: str = option("ours", choices=PROTOCOLS,
                           help="exavatar: also ExAvatar's numbers (composited over white outside the GT mask, full "
                                "image, PSNR/SSIM data range 1, LPIPS-AlexNet, mean over frames)")
    poses: str = option("run", choices=POSES,
                        help="render at the subject's stored poses as the run corrected them (run: trioman train "
                             "--refine-poses; the stored ones for a run without), at the stored poses as they are "
                             "(stored), or at the recorded ground-truth poses (true: synthetic subjects made with "
                             "--pose-noise; measures the avatar, not the pose noise), or at the run's poses refitted to "
                             "each frame's own pixels with the avatar frozen (optimised: fitted videos; test-time pose "
                             f"optimisation: L-BFGS at full size until it converges, at most {REFIT_STEPS} iterations a frame; "
                             "far slower than the other choices)")
    video: bool = option(True, help="write the MP4 of the frames")

    def __post_init__(self) -> None:
        check_options(self)
