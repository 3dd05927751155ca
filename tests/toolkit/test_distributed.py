"""Data-parallel training (toolkit/distributed.py) on CPU with gloo: two processes with half the batch
each train the weights of one process with the whole batch, resume exactly at the same world size
and refuse another; ``torchrun -m trioman train-refiner`` end to end; the device parametrised (CUDA
cases skip without it)."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.toolkit.factories import fake_triplets  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.toolkit.corpus.build import CORPUS_JSON  # noqa: E402
from trioman.toolkit.distributed import Ranks, process_group  # noqa: E402
from trioman.toolkit.lpips import NOT_FOUND_MESSAGE, find_lpips_weights  # noqa: E402
from trioman.toolkit.corpus.training import FitConfig, SampleStream, fit_examiner, fit_refiner  # noqa: E402
from trioman.toolkit.loops.checkpoint import latest_checkpoint, load_checkpoint  # noqa: E402
from trioman.toolkit.corpus.triplets import TripletSet  # noqa: E402

BATCH = 2  # per rank; one process trains on 2 x BATCH
SGD_LR = 0.05

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available() or torch.cuda.device_count() < 2,
                                                                reason="needs two CUDA devices"))]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    subjects = [{"name": "s00", "role": "train"}, {"name": "s01", "role": "train"}, {"name": "s02", "role": "heldout"}]
    for i, s in enumerate(subjects):
        folder = root / "triplets" / ("all" if s["role"] == "train" else "heldout")
        folder.mkdir(parents=True, exist_ok=True)
        fake_triplets(folder / f"{s['name']}.npz", seed=i)
    (root / CORPUS_JSON).write_text(json.dumps({"config": {}, "subjects": subjects}))
    return root


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _fit(model: str, corpus: Path, run: Path, steps: int, batch: int, device: str) -> None:
    if model == "refiner":
        fit_refiner(corpus, run, "tex+geo", FitConfig(steps=steps, batch=batch, crop=16), device=device)
    else:
        fit_examiner(corpus, run, "examiner_nano", FitConfig(steps=steps, batch=batch, lr=3e-4, crop=None), "paper",
                     validation_subjects=1, device=device)


def plain_sgd(setattr) -> None:
    """The loops' Adam as SGD with momentum and no gradient clipping: an update is then proportional to the
    gradient, so a wrong gradient scale across ranks changes the weights (Adam's updates would not show it)."""
    setattr(torch.optim, "Adam", lambda params, lr, **_: torch.optim.SGD(params, lr=SGD_LR, momentum=0.9))
    setattr(torch.nn.utils, "clip_grad_norm_", lambda parameters, max_norm, **_: None)


def _worker(rank: int, world: int, port: int, model: str, corpus: Path, root: Path, device: str) -> None:
    """One rank of a torchrun-like launch, with ``plain_sgd``: a 3-step run, and a 2-step run resumed to 3 steps."""
    plain_sgd(setattr)
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), WORLD_SIZE=str(world), RANK=str(rank),
                      LOCAL_RANK=str(rank))
    torch.set_num_threads(1)
    with process_group(device):
        _fit(model, corpus, root / "straight", 3, BATCH, device)
        _fit(model, corpus, root / "resumed", 2, BATCH, device)
        _fit(model, corpus, root / "resumed", 3, BATCH, device)


def weights(run: Path) -> dict:
    return load_checkpoint(latest_checkpoint(run))["model"]


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("model", ["refiner", "examiner"])
def test_two_processes_train_the_one_process_weights_resume_exactly_and_refuse_another_world_size(model, device, corpus, tmp_path,
                                                                                                 monkeypatch):
    torch.multiprocessing.spawn(_worker, args=(2, free_port(), model, corpus, tmp_path, device), nprocs=2)
    plain_sgd(monkeypatch.setattr)
    _fit(model, corpus, tmp_path / "one", 3, 2 * BATCH, device)
    one, two = weights(tmp_path / "one"), weights(tmp_path / "straight")
    assert max((one[k] - two[k]).abs().max().item() for k in one) < 1e-5
    resumed = weights(tmp_path / "resumed")
    assert all(torch.equal(two[k], resumed[k]) for k in two)  # exact at the same world size
    if model == "examiner":
        from trioman.toolkit.examiner import load_examiner

        x = torch.rand(4, 3, 32, 32, generator=torch.Generator().manual_seed(0))
        a, b = (load_examiner(latest_checkpoint(tmp_path / r)) for r in ("one", "straight"))
        assert (a(x, x.flip(0)) - b(x, x.flip(0))).abs().max() < 1e-5
    info = json.loads((tmp_path / "straight" / "fit.json").read_text())["distributed"]
    assert info["world_size"] == 2 and info["global_batch"] == 2 * BATCH
    assert [r["rows"] for r in info["ranks"]] == [[0, BATCH], [BATCH, 2 * BATCH]]
    with pytest.raises(ValueError, match="world_size: .* written by a run of 2 process.*this one has 1"):
        _fit(model, corpus, tmp_path / "resumed", 4, 2 * BATCH, device)


def test_the_stream_gives_each_rank_its_rows_of_the_one_process_batch(corpus):
    data = TripletSet.load(sorted((corpus / "triplets" / "all").glob("*.npz")))
    fit = FitConfig(batch=2, crop=16, seed=3)
    whole = SampleStream(data, FitConfig(batch=4, crop=16, seed=3))
    parts = [SampleStream(data, fit, Ranks(r, 2)) for r in range(2)]
    for step in (0, 1, 5):  # a later step skips the ones in between, as a resumed run does
        w, p = whole(step), [s(step) for s in parts]
        for field in range(len(w)):
            assert np.array_equal(w[field], np.concatenate([p[0][field], p[1][field]]))
    with pytest.raises(ValueError, match="step: the stream is at step 6, cannot go back to 2"):
        whole(2)


def test_torchrun_train_refiner_rank_zero_writes(corpus, tmp_path):
    run2 = tmp_path / "two"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--rdzv-backend", "c10d",
           "--rdzv-endpoint", f"127.0.0.1:{free_port()}", "-m", "trioman", "train-refiner", "--corpus", str(corpus),
           "--out", str(run2), "--steps", "2", "--batch", str(BATCH), "--crop", "16"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr[-2000:]
    said = int(find_lpips_weights() is None)  # rank 0 alone says once that LPIPS is not computed, when it is not
    assert done.stdout.count("(warp+geo, 2 steps") == 1 and done.stdout.count(NOT_FOUND_MESSAGE) == said
    assert main(["train-refiner", "--corpus", str(corpus), "--out", str(tmp_path / "one"), "--steps", "2", "--batch",
                 str(2 * BATCH), "--crop", "16"]) == 0
    one, two = weights(tmp_path / "one"), weights(run2)
    assert max((one[k] - two[k]).abs().max().item() for k in one) < 1e-5
    assert sorted(p.name for p in run2.iterdir()) == ["checkpoints", "fit.json"]
    assert not [p for p in run2.rglob("*") if ".tmp" in p.name]


def test_device_is_cpu_or_cuda(corpus, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["train-examiner", "--corpus", str(corpus), "--out", str(tmp_path / "x"), "--device", "tpu"])
    assert "invalid choice: 'tpu'" in capsys.readouterr().err
    if not torch.cuda.is_available():
        assert main(["train-examiner", "--corpus", str(corpus), "--out", str(tmp_path / "x"), "--device", "cuda"]) == 1
        assert "--device cuda: CUDA is not available" in capsys.readouterr().err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("model", ["refiner", "examiner"])
def test_one_process_trains_on_cuda_in_bf16(model, corpus, tmp_path):
    args = ["--corpus", str(corpus), "--out", str(tmp_path / model), "--steps", "2", "--batch", "2", "--device", "cuda",
            "--mixed-precision", "bf16"]
    assert main([f"train-{model}", *args, *(["--crop", "16"] if model == "refiner" else [])]) == 0
    assert all(torch.isfinite(v).all() for v in weights(tmp_path / model).values() if v.is_floating_point())
