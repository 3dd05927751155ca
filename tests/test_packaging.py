"""pyproject.toml lists every package folder, so a wheel (``pip install .``, not only the editable install of
``make install``) holds the whole library."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_in_the_wheel():
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {p.parent.relative_to(ROOT).as_posix()
               for top in ("trioman", "runtime", "toolkit", "export", "bench") for p in (ROOT / top).rglob("__init__.py")}
    listed = {setup["package-dir"].get(name, name.replace(".", "/")) for name in setup["packages"]}
    assert folders - listed == set(), "package folders missing from pyproject.toml [tool.setuptools] packages"
    assert listed - folders == set(), "pyproject.toml lists package folders that do not exist"


def test_the_shipped_models_are_package_data():
    import fnmatch

    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = setup["package-data"]["trioman.runtime"]
    shipped = [p.relative_to(ROOT / "runtime").as_posix() for p in (ROOT / "runtime" / "pretrained").iterdir()
               if p.name != "__pycache__"]
    assert {"pretrained/models.json", "pretrained/refiner.onnx", "pretrained/examiner.onnx"} <= set(shipped)
    assert all(any(fnmatch.fnmatch(f, pat) for pat in patterns) for f in shipped), (shipped, patterns)
