"""What ``trioman export avatar`` and ``trioman export onnx`` write (export/avatar.py, export/onnx_models/), each setting
with its option (runtime/options.py): the library's defaults and the command's are these fields. Standard-library
imports only: the command builds its parsers from these fields."""

from __future__ import annotations

from dataclasses import dataclass

from trioman.runtime.options import check_options, option

VARIANTS = ("fp32", "int8", "fp16")  # the ONNX files' precisions


@dataclass(frozen=True)
class AvatarExportOptions:
    pose_dependent: bool = option(True, help="the pose-dependent terms (their ONNX graph)")
    ply_frames: tuple[int, ...] = option((), flag="--ply-frame", metavar="I", repeat=True,
                                         help="also write posed_I.ply at subject frame I's pose (repeatable)")

    def __post_init__(self) -> None:
        check_options(self)


@dataclass(frozen=True)
class OnnxExportOptions:
    variants: tuple[str, ...] = option(VARIANTS, sep=",", choices=VARIANTS, metavar="LIST",
                                       help="comma-separated subset of fp32,int8,fp16")
    calibration: tuple[str, ...] | None = option(None, metavar="TRIPLETS.npz", default_text="synthetic random images",
                                                 help="triplet files (trioman triplets) for int8 calibration, the int8 "
                                                      "gates and real-frame parity")
    size: int | None = option(None, default_text="the calibration frames' size, else its config's image_size",
                              help="the Refiner's export size N x N")

    def __post_init__(self) -> None:
        check_options(self)
