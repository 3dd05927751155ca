"""A model's run (toolkit.loops.model_run): resume, the keywords of the avatar's loop, and the bar opened late."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import pytest
import torch

from trioman.toolkit.loops.checkpoint import ConfigMismatch, list_checkpoints, load_checkpoint
from trioman.toolkit.loops.model_run import ModelRun


@dataclass(frozen=True)
class Config:
    width: int = 2

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Loop:
    steps: int = 4
    checkpoint_every: int = 2
    keep_checkpoints: int = 2
    max_skipped: int = 3

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Model(torch.nn.Linear):
    def __init__(self, config: Config = Config()) -> None:
        super().__init__(config.width, 1)
        self.config = config


def run_steps(run, loop_config=Loop(), model=None, what="model", **kw) -> ModelRun:
    torch.manual_seed(0)
    model = model or Model()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.1)
    loop = ModelRun("m", what, model, optimizer, loop_config, run, False, **kw)
    while loop.running:
        optimizer.zero_grad()
        loss = model(torch.ones(1, model.config.width)).square().sum()
        loss.backward()
        optimizer.step()
        if loop.advance(float(loss.detach())):
            loop.check_weights()
            loop.save(loop.state())
    loop.finish()
    return loop


def test_a_run_resumes_from_its_newest_checkpoint_and_refuses_another_config(tmp_path):
    done = run_steps(tmp_path / "r")
    assert done.step == 4 and [p.name for p in list_checkpoints(tmp_path / "r")] == ["ckpt_0000002.pt", "ckpt_0000004.pt"]
    again = run_steps(tmp_path / "r")
    assert again.step == 4 and again.losses == [] and again.resumed["step"] == 4
    with pytest.raises(ConfigMismatch, match="the run's model differs from this one \\(width: 2 -> 3\\)"):
        run_steps(tmp_path / "r", model=Model(Config(width=3)))


def test_the_avatar_loops_keywords(tmp_path):
    run_steps(tmp_path / "r")
    # what None: the caller checked the run's config, the checkpoint's is not compared (its state loads)
    with pytest.raises(RuntimeError, match="size mismatch"):
        run_steps(tmp_path / "r", model=Model(Config(width=3)), what=None)
    # resume False: no checkpoint is looked for; steps: the run's length, not config.steps
    fresh = run_steps(tmp_path / "r", resume=False, steps=6)
    assert fresh.step == 6 and len(fresh.losses) == 6 and fresh.resumed == {}
    assert load_checkpoint(list_checkpoints(tmp_path / "r")[-1])["step"] == 6


def test_the_bar_opens_when_asked_or_at_the_first_step(tmp_path):
    model = Model()
    loop = ModelRun("m", "model", model, torch.optim.SGD(model.parameters(), lr=0.1), Loop(), None, False, open_bar=False,
                    unit="it")
    assert loop._bar is None
    loop.advance(1.0)
    assert loop._bar is not None
    assert loop.open_bar() is loop._bar
    loop.finish()
