"""``trioman synth-corpus --shard I/N`` and ``--merge``: shards of a tiny corpus merge into the files of a
one-process build; a missing, failed or differently-set shard makes the merge fail naming it."""

import csv
import io
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

import trioman.toolkit.corpus.build as corpus_mod  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.toolkit.corpus.build import CorpusConfig, build_corpus  # noqa: E402

ARGS = ["--subjects", "1", "--heldout", "1", "--size", "32", "--frames", "8", "--iterations", "2", "--quiet"]
CFG = CorpusConfig(train_subjects=1, heldout_subjects=1, size=32, frames=8, iterations=2)


def snapshot(root: Path) -> dict:
    """Every file's bytes, except the baselines' wall-clock times: train_log.csv without its seconds
    column, and checkpoints as their entries without "seconds"."""
    files = {}
    for p in sorted(root.rglob("*")):
        if not p.is_file():
            continue
        rel = p.relative_to(root).as_posix()
        if p.name == "train_log.csv":
            files[rel] = [row[:1] + row[2:] for row in csv.reader(io.StringIO(p.read_text()))]
        elif p.suffix == ".pt":
            state = torch.load(p, weights_only=True)
            state.pop("seconds")
            buf = io.BytesIO()
            torch.save(state, buf)
            files[rel] = buf.getvalue()
        else:
            files[rel] = p.read_bytes()
    return files


def test_shards_merge_into_the_one_process_corpus_and_a_bad_shard_is_named(tmp_path, monkeypatch, capsys):
    root = tmp_path / "corpus"  # both builds at one path: the triplet files record it
    build_corpus(root, CFG, progress=False)
    one = snapshot(root)
    root.rename(tmp_path / "one")

    assert main(["synth-corpus", "--out", str(root), *ARGS, "--shard", "1/2"]) == 0
    assert "shard 1/2: 1 of 1 training + 1 held-out subjects" in capsys.readouterr().out
    assert main(["synth-corpus", "--out", str(root), *ARGS, "--merge"]) == 1
    assert "--merge: shard 0/2 is missing: no " in capsys.readouterr().err

    def boom(*args):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(corpus_mod, "_build_subject", boom)
    with pytest.raises(RuntimeError):
        main(["synth-corpus", "--out", str(root), *ARGS, "--shard", "0/2"])
    assert main(["synth-corpus", "--out", str(root), *ARGS, "--merge"]) == 1
    assert "--merge: shard 0/2 failed (RuntimeError: disk on fire); run it again with --shard 0/2" in capsys.readouterr().err
    monkeypatch.undo()

    assert main(["synth-corpus", "--out", str(root), *ARGS, "--shard", "0/2"]) == 0
    assert main(["synth-corpus", "--out", str(root), *ARGS[:-3], "--iterations", "3", "--merge"]) == 1
    assert "--merge: shard 0/2 ran with other settings (iterations: 2, the merge has 3)" in capsys.readouterr().err
    assert not (root / "corpus.json").exists()
    assert main(["synth-corpus", "--out", str(root), *ARGS, "--merge"]) == 0
    assert snapshot(root) == one  # the shard records are gone too


@pytest.mark.parametrize("value", ["2/2", "1", "a/b"])
def test_a_bad_shard_is_one_line(value, tmp_path, capsys):
    assert main(["synth-corpus", "--out", str(tmp_path), *ARGS, "--shard", value]) == 1
    assert f"--shard: expected I/N with 0 <= I < N (e.g. 0/4), got '{value}'" in capsys.readouterr().err
