"""``trioman augment --shard I/N`` and ``--merge`` (runtime/shards.py): shards of a tiny augment run merge
into the files of a one-process run (timings aside); a missing shard or one with other settings makes
the merge fail naming it."""

import pytest

from tests.runtime.augment_runs import LIMIT, snapshot
from trioman.cli import main
from trioman.runtime.shards import Shard


def argv(inputs, out, *extra):  # the flags of tests.runtime.augment_runs.run()
    return ["augment", str(inputs.subject), "--avatar", str(inputs.avatar), "--refiner", str(inputs.refiner), "--examiner",
            str(inputs.examiner), "--out", str(out), "--frames", "all", "--limit", str(LIMIT), "--seed", "7", "--no-keep-carried", "--quiet", *extra]


def test_shards_merge_into_the_one_process_output(inputs, straight, tmp_path, capsys):
    out = tmp_path / "sharded"
    assert main(argv(inputs, out, "--shard", "2/3")) == 0
    assert "augment: shard 2/3 done (1 source frames" in capsys.readouterr().out
    assert main(argv(inputs, out, "--merge")) == 1
    assert "--merge: shard 0/3 is missing: no " in capsys.readouterr().err
    assert main(argv(inputs, out, "--shard", "0/3")) == 0
    assert main(argv(inputs, out, "--shard", "1/3", "--seed", "8")) == 0
    assert main(argv(inputs, out, "--merge")) == 1
    assert "--merge: shard 1/3 ran with other settings (seed: 8, the merge has 7)" in capsys.readouterr().err
    assert main(argv(inputs, out, "--shard", "1/3", "--overwrite")) == 0
    assert main(argv(inputs, out, "--merge")) == 0
    assert snapshot(out) == straight.files  # byte-identical images, masks, frames.npz, subject.json, histogram


@pytest.mark.parametrize("corrupt, message", [
    (lambda rec: {**rec, "candidates": [{**rec["candidates"][0], "score": float("nan")}] + rec["candidates"][1:]},
     "is not valid JSON"),  # NaN written as JSON's NaN
    (lambda rec: {**rec, "candidates": [{**rec["candidates"][0], "score": 3.0}] + rec["candidates"][1:]},
     r"candidates\[0\]\.score: expected null or a number in \[0, 1\], got 3.0"),
    (lambda rec: {**rec, "frames": [{**rec["frames"][0], "name": "../../../x"}]}, r"frames\[0\]\.name"),
    (lambda rec: {**rec, "seed": "abc"}, "seed: expected an integer"),
    (lambda rec: {**rec, "seed": rec["seed"] + 1}, r"seed: expected \d+ \(the run's seed 7 for frame "),  # issue 41, D9
    (None, "malformed JSON"),  # truncated
])
def test_a_corrupt_shard_record_is_named_and_nothing_moves(inputs, tmp_path, capsys, corrupt, message):
    import json
    import re

    out = tmp_path / "sharded"
    for i in range(2):
        assert main(argv(inputs, out, "--shard", f"{i}/2")) == 0
    capsys.readouterr()
    record = sorted((out / "shards" / "1-of-2" / "records").glob("*.json"))[0]
    text = record.read_text()
    record.write_text(text[: len(text) // 2] if corrupt is None else json.dumps(corrupt(json.loads(text))))
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    assert main(argv(inputs, out, "--merge")) == 1
    err = capsys.readouterr().err
    assert str(record) in err and len(re.findall(message, err)) == 1 and err.count("\n") == 1, err
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # nothing moved, no augment.json


def test_shard_rule_and_parse():
    assert Shard.parse("1/3").take(list("abcdefg")) == ["b", "e"]
    assert Shard.parse(" 0/1 ").name == "0-of-1"
    with pytest.raises(ValueError, match=r"^shard: expected I/N with 0 <= I < N \(e.g. 0/4\), got '3/3'"):
        Shard.parse("3/3")


def test_a_swapped_frame_file_in_a_shard_is_named_and_nothing_moves(inputs, tmp_path, capsys):
    """Issue 26 (minor): a PNG swapped inside a shard went unnoticed at --merge; records keep each file's sha256."""
    import json

    out = tmp_path / "sharded"
    for i in range(2):
        assert main(argv(inputs, out, "--shard", f"{i}/2")) == 0
    capsys.readouterr()
    shard = out / "shards" / "1-of-2"
    record = sorted((shard / "records").glob("*.json"))[0]
    frame = json.loads(record.read_text())["frames"][0]["name"]
    image, mask = shard / "images" / f"{frame}.png", shard / "masks" / f"{frame}.png"
    kept = image.read_bytes()
    image.write_bytes(mask.read_bytes())  # a valid PNG, the wrong one
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    assert main(argv(inputs, out, "--merge")) == 1
    err = capsys.readouterr().err
    assert f"{record}: frames[0].sha256.images: {image} is not the file that was written" in err and err.count("\n") == 1
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # nothing moved, no augment.json

    image.write_bytes(kept)  # records written before the hashes were kept merge as before
    for path in (out / "shards").glob("*/records/*.json"):
        rec = json.loads(path.read_text())
        path.write_text(json.dumps({**rec, "frames": [{k: v for k, v in f.items() if k != "sha256"} for f in rec["frames"]]}))
    assert main(argv(inputs, out, "--merge")) == 0


def test_a_shard_frame_that_is_a_link_is_named_and_nothing_moves(inputs, tmp_path, capsys):
    """Issue 41, D9: --merge moved a link to a file outside into the output (the same bytes pass the sha256)."""
    import json
    import shutil

    out = tmp_path / "sharded"
    for i in range(2):
        assert main(argv(inputs, out, "--shard", f"{i}/2")) == 0
    capsys.readouterr()
    shard = out / "shards" / "1-of-2"
    frame = json.loads(sorted((shard / "records").glob("*.json"))[0].read_text())["frames"][0]["name"]
    image, outside = shard / "images" / f"{frame}.png", tmp_path / "outside.png"
    shutil.move(image, outside)
    image.symlink_to(outside)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    assert main(argv(inputs, out, "--merge")) == 1
    err = capsys.readouterr().err
    assert f"{image}: expected a file written by the shard's job, found a link" in err and err.count("\n") == 1, err
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before and image.is_symlink()
