"""A run started from another run's checkpoint (``fork_run``): the rows of an ablation share the real-frame
warm-up of their unaugmented control instead of each training it again.

Steps before the augmentation's warm-up ends (``AugmentConfig.start``) read nothing of the augmentation: the
frames, backgrounds and learning rates come from the run's seed and length alone. A run forked at such a step
from a run whose config differs only in ``augment`` and ``checkpoint_every`` therefore goes on to the weights
of the same run trained from scratch, bit for bit, at the same torch thread count.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
from pathlib import Path

import torch

from trioman.runtime.formats import load_subject
from trioman.toolkit.loops.checkpoint import checkpoint_path, load_checkpoint, save_checkpoint
from trioman.toolkit.train.augmentation import Augmenter
from trioman.toolkit.train.config import TrainConfig, with_subject_defaults
from trioman.toolkit.train.loop import TRAIN_LOG
from trioman.toolkit.train.resume import config_differences, new_record, read_record, write_record


def fork_step(cfg: TrainConfig) -> int:
    """The last step a run of ``cfg`` can be forked at: the end of its augmentation's warm-up (its length
    without augmentation)."""
    return cfg.iterations if cfg.augment is None else cfg.augment.start_step(cfg.iterations)


def fork_run(source: str | Path, run: str | Path, cfg: TrainConfig, step: int) -> Path:
    """Make ``run`` (config ``cfg``) as the unaugmented run ``source`` stood at ``step`` (its checkpoint there):
    weights, optimizer, random states, time and log; ``train(subject, run, cfg, resume=True)`` goes on from
    there. The folder appears whole or not at all. ValueError naming what forbids the fork: an augmented
    source, a config differing in more than ``augment`` and ``checkpoint_every``, a step past ``fork_step``,
    another torch thread count than the source's."""
    source, run = Path(source), Path(run)
    if run.exists():
        raise FileExistsError(f"run: {run} already exists (a fork makes a new run)")
    record = read_record(source)
    base = TrainConfig.from_dict(record["train"])
    cfg = with_subject_defaults(cfg, record.get("subject_tool"))  # as the source's were resolved
    if base.augment is not None:
        raise ValueError(f"source: {source} trains with augmentation; fork from an unaugmented run")
    diff = config_differences(base, dataclasses.replace(cfg, augment=None, checkpoint_every=base.checkpoint_every))
    if diff:
        raise ValueError(f"source: {source}'s config differs in more than augmentation ({'; '.join(diff[:4])})")
    if isinstance(step, bool) or not isinstance(step, int) or not 0 < step <= fork_step(cfg):
        raise ValueError(f"step: a fork starts within the augmentation's warm-up, 1..{fork_step(cfg)}, got {step!r}")
    if record.get("threads") != torch.get_num_threads():
        raise ValueError(f"source: {source} was trained with {record.get('threads')} torch threads, this process has "
                         f"{torch.get_num_threads()}: the fork would not match a run from scratch")
    state = load_checkpoint(checkpoint_path(source, step))
    state["config"] = json.dumps(cfg.to_dict())
    if cfg.augment is not None:
        state["augment"] = Augmenter.initial_state(cfg.seed)
    run.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{run.name}.", dir=run.parent))
    try:
        save_checkpoint(tmp, step, state, keep=cfg.keep_checkpoints)
        shutil.copyfile(source / TRAIN_LOG, tmp / TRAIN_LOG)  # the resume trims it to the checkpoint's step
        write_record(tmp, {**new_record(load_subject(record["subject"]), cfg),
                           "forked_from": {"run": str(source.resolve()), "step": step}})
        tmp.rename(run)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return run
