"""The Refiner (paper 3.2.5): a one-step multi-view latent U-Net (Difix-like) trained from scratch,
its backbone registry, loss, training loop and ONNX example inputs."""

from trioman.toolkit.refiner.backbones import BackboneUnavailable, create_refiner, register_backbone, registered_backbones
from trioman.toolkit.refiner.batch import RefinerBatch, check_batch, refiner_inputs, refiner_targets
from trioman.toolkit.refiner.config import CONDITIONS, RefinerConfig
from trioman.toolkit.refiner.loop import RefinerTrainConfig, RefinerTrainResult, load_refiner, refiner_loop, train_step
from trioman.toolkit.refiner.loss import RefinerLossWeights, refiner_loss
from trioman.toolkit.refiner.model import INPUT_NAMES, OUTPUT_NAME, Refiner, export_inputs

__all__ = [
    "CONDITIONS",
    "INPUT_NAMES",
    "OUTPUT_NAME",
    "BackboneUnavailable",
    "Refiner",
    "RefinerBatch",
    "RefinerConfig",
    "RefinerLossWeights",
    "RefinerTrainConfig",
    "RefinerTrainResult",
    "check_batch",
    "create_refiner",
    "export_inputs",
    "load_refiner",
    "refiner_inputs",
    "refiner_loop",
    "refiner_loss",
    "refiner_targets",
    "register_backbone",
    "registered_backbones",
    "train_step",
]
