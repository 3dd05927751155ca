"""The Examiner (paper 3.2.6): a dual-branch attention similarity network on a timm-style ViT,
its training pairs, loss, training loop, inference choice and AUROC."""

from trioman.toolkit.examiner.inference import BatchChoice, choose
from trioman.toolkit.examiner.loop import ExaminerTrainConfig, ExaminerTrainResult, examiner_loop, load_examiner
from trioman.toolkit.examiner.loss import examiner_loss
from trioman.toolkit.examiner.metrics import auroc, pair_auroc
from trioman.toolkit.examiner.model import (
    EXAMINER_CONFIGS,
    Examiner,
    ExaminerConfig,
    PatchLogits,
    create_examiner,
    examiner_config,
    export_inputs,
)
from trioman.toolkit.examiner.pairs import ExaminerBatch, ExaminerPairs, sample_pairs

__all__ = [
    "EXAMINER_CONFIGS",
    "BatchChoice",
    "Examiner",
    "ExaminerBatch",
    "ExaminerConfig",
    "ExaminerPairs",
    "ExaminerTrainConfig",
    "ExaminerTrainResult",
    "PatchLogits",
    "auroc",
    "choose",
    "create_examiner",
    "examiner_config",
    "examiner_loop",
    "examiner_loss",
    "export_inputs",
    "load_examiner",
    "pair_auroc",
    "sample_pairs",
]
