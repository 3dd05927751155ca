"""``trioman view`` without viser names the extra to install, in one line, and starts nothing."""

from tests.conftest import run_python


def test_without_viser_the_viewer_extra_is_named(tmp_path):
    proc = run_python(f"import sys; sys.modules['viser'] = None\n"
                      f"from trioman.cli import main; sys.exit(main(['view', {str(tmp_path)!r}]))", block_torch=True)
    assert proc.returncode == 1
    assert proc.stderr.strip() == ("trioman view: error: 'trioman view' needs the 'viewer' extra, and viser is not "
                                   "installed: pip install 'trioman[viewer]'")
