"""Errors a user can cause are one line, never a traceback (trioman/cli.py)."""

import json

import pytest

from trioman import cli


def test_a_recursion_error_is_one_line(tmp_path, monkeypatch, capsys):
    # A reader that recurses into a deeply nested file (json.loads) and names no file: one line, no traceback.
    deep = tmp_path / "fit.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)

    def run(args):
        return json.loads(deep.read_text())

    monkeypatch.setattr("trioman.commands.inspect.run", run)
    assert cli.main(["inspect", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.strip() == ("trioman inspect: error: an input is nested too deeply to read (maximum recursion depth "
                           "exceeded); TRIOMAN_DEBUG=1 shows where")
    monkeypatch.setenv("TRIOMAN_DEBUG", "1")
    with pytest.raises(RecursionError):
        cli.main(["inspect", str(tmp_path)])
