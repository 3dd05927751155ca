"""``trioman synth-corpus``: synthetic subjects for training and evaluating the Refiner and Examiner, each with a
baseline avatar and a triplet file (``build_corpus``; sharded jobs and ``merge_corpus``: docs/scaling.md).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

from trioman.runtime.shards import SHARDS_DIR, Shard, check_shards, shard_run
from trioman.toolkit.corpus.config import CorpusConfig

CORPUS_JSON = "corpus.json"


def finished(run: Path, iterations: int) -> bool:
    from trioman.toolkit.loops.checkpoint import latest_checkpoint

    ckpt = latest_checkpoint(run) if (run / "config.json").exists() else None
    return ckpt is not None and int(ckpt.stem.split("_")[-1]) >= iterations


def triplet_paths(root: str | Path, baseline_frames: str = "all") -> dict[str, list[Path]]:
    """The triplet files of a built corpus by role: {"train": [...], "heldout": [...]}."""
    root = Path(root)
    meta = json.loads((root / CORPUS_JSON).read_text())
    out: dict[str, list[Path]] = {"train": [], "heldout": []}
    for s in meta["subjects"]:
        p = root / "triplets" / (baseline_frames if s["role"] == "train" else "heldout") / f"{s['name']}.npz"
        if not p.is_file():
            raise FileNotFoundError(f"{p}: missing triplet file (build the corpus with `baseline_frames` {baseline_frames})")
        out[s["role"]].append(p)
    return out


def _paths(root: Path, cfg: CorpusConfig, name: str, role: str) -> tuple[Path, Path, Path]:
    """(subject folder, baseline run, triplet file) of one subject."""
    variant = cfg.baseline_frames if role == "train" else "heldout"
    return root / "subjects" / name, root / "runs" / variant / name, root / "triplets" / variant / f"{name}.npz"


def _build_subject(root: Path, cfg: CorpusConfig, i: int, progress: bool) -> None:
    """Subject i's synthesis, baseline and triplets, each skipped when already complete."""
    from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject
    from trioman.toolkit.train.config import preset
    from trioman.toolkit.train.loop import train
    from trioman.toolkit.corpus.triplets import TRIPLETS_VERSION, build_triplets, triplets_version

    name, role = cfg.names[i]
    subject, run, trip = _paths(root, cfg, name, role)
    if not (subject / "subject.json").is_file():
        synthesize_subject(SynthConfig(seed=cfg.seed + i, size=cfg.size, frames=cfg.frames, style=cfg.style), subject,
                           progress=progress)
    if not finished(run, cfg.iterations):
        frames = {"frames": "all"} if role == "train" else {}
        if role == "train" and cfg.baseline_frames == "subset":
            frames["frame_stride"] = cfg.subset_stride
        train_cfg = preset("quick", iterations=cfg.iterations, checkpoint_every=cfg.iterations, **frames)
        train(subject, run, train_cfg, resume=(run / "config.json").exists(), progress=progress)
    if not trip.is_file() or triplets_version(trip) < TRIPLETS_VERSION:  # older files lack the aligned references
        build_triplets(run, trip, progress=progress)
    if progress:
        print(f"synth-corpus: {name} ({role}) done: {trip}")


def _settings(cfg: CorpusConfig) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _write_corpus_json(root: Path, cfg: CorpusConfig) -> None:
    from trioman.runtime.outputs import atomic_write_text

    subjects = [{"name": name, "role": role, "seed": cfg.seed + i} for i, (name, role) in enumerate(cfg.names)]
    atomic_write_text(root / CORPUS_JSON, json.dumps({"config": dataclasses.asdict(cfg), "subjects": subjects}, indent=2) + "\n")


def build_corpus(root: str | Path, cfg: CorpusConfig, progress: bool = True, shard: Shard | None = None) -> Path:
    """Build the corpus in ``root`` (resumable). With ``shard``, only that shard's subjects and its
    record in root/shards, no corpus.json (``merge_corpus`` writes it).

    The paper trains the Refiner and Examiner on 17 X-Humans subjects and evaluates on 3 others; here:
    ``cfg.train_subjects`` synthetic subjects and ``cfg.heldout_subjects``, each with a baseline avatar and a
    triplet file (toolkit/corpus/triplets.py). Baselines of training subjects are trained on ``cfg.baseline_frames``:
    "all" frames (the paper's choice: coarse frames carry reconstruction error only) or "subset" (every
    ``subset_stride``-th frame, so most coarse frames carry real novel-pose error). Held-out subjects'
    baselines see their train split only, and evaluation uses their test frames (novel poses and views).

    Layout: root/corpus.json, root/subjects/sNN/, root/runs/<variant>/sNN/, root/triplets/<variant>/sNN.npz
    with variant = ``baseline_frames`` for training subjects and "heldout" for held-out ones. Every piece is
    written atomically and skipped when already complete, so an interrupted build resumes. A shard I/N builds
    the whole subjects (synthesis, baseline, triplets) at positions p with p % N == I."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    for variant in (cfg.baseline_frames, "heldout"):
        for sub in ("runs", "triplets"):
            (root / sub / variant).mkdir(parents=True, exist_ok=True)
    positions = list(range(len(cfg.names)))
    if shard is None:
        for i in positions:
            _build_subject(root, cfg, i, progress)
        _write_corpus_json(root, cfg)
        return root
    mine = shard.take(positions)
    with shard_run(root, shard, _settings(cfg), [cfg.names[i][0] for i in mine]):
        for i in mine:
            _build_subject(root, cfg, i, progress)
    return root


def merge_corpus(root: str | Path, cfg: CorpusConfig) -> Path:
    """corpus.json of a corpus built by shards, after checking that every shard finished with ``cfg``
    (runtime/shards.py) and that every subject's files are there; then the shard records go."""
    root = Path(root)
    check_shards(root, _settings(cfg))
    for name, role in cfg.names:
        subject, run, trip = _paths(root, cfg, name, role)
        for path, ok in ((subject / "subject.json", (subject / "subject.json").is_file()),
                         (run, finished(run, cfg.iterations)), (trip, trip.is_file())):
            if not ok:
                raise ValueError(f"merge: subject {name} is incomplete: {path} (run its shard again)")
    _write_corpus_json(root, cfg)
    shutil.rmtree(root / SHARDS_DIR)
    return root
