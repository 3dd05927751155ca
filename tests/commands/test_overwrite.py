"""``--overwrite`` through the commands: a folder that is not the command's own kind is refused, naming its
first foreign file, and nothing in it is removed (runtime.outputs.check_folder_target; export avatar's case
is in tests/export/test_avatar.py, the library rule in tests/runtime/test_image_io.py)."""

import pytest

from trioman.cli import main


def test_synth_overwrite_keeps_a_folder_it_did_not_write(tmp_path, capsys):
    pytest.importorskip("torch")
    pytest.importorskip("anny")
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.txt").write_text("three years")
    argv = ["synth", "--out", str(out), "--size", "32", "--frames", "6", "--quiet", "--overwrite"]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"trioman synth: error: --overwrite: {out / 'thesis.txt'} was not written by trioman (the folder holds "
                   f"no subject.json: not a trioman subject folder); refusing to replace {out} (move it away, or choose "
                   f"another output folder)")
    assert [p.name for p in out.iterdir()] == ["thesis.txt"] and [p.name for p in tmp_path.iterdir()] == ["mine"]
