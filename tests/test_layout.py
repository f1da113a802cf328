"""The package's layout: which subpackage may import which, file sizes, and every public name importable."""

import ast
import importlib
import pkgutil
import tomllib
from pathlib import Path

import pytest

import prismap

SRC = Path(prismap.__file__).parent
SUBPACKAGES = sorted(m.name for m in pkgutil.iter_modules([str(SRC)]) if m.ispkg)
MAX_LINES = 600
GRID_MUST_NOT_IMPORT = ("camera", "stereo", "sensor_models", "io")


def _imported_subpackages(path):
    """The ``prismap`` subpackages a module imports anywhere (top level or inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            parts = node.module.split(".")
            if parts[0] != "prismap":
                continue
            if len(parts) > 1:
                found.add(parts[1])
            else:  # from prismap import camera
                found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "prismap" and len(parts) > 1:
                    found.add(parts[1])
        elif isinstance(node, ast.ImportFrom) and node.level > 0:
            raise AssertionError(f"{path}: relative import (the package uses absolute imports)")
    return found


def test_the_import_scan_sees_every_form_of_import(tmp_path):
    module = tmp_path / "m.py"
    module.write_text(
        "import prismap.io._npz\nfrom prismap import camera, errors\n\n"
        "def f():\n    from prismap.stereo._base import to_grey\n"
    )
    assert _imported_subpackages(module) == {"io", "camera", "errors", "stereo"}


@pytest.mark.parametrize("path", sorted((SRC / "grid").glob("*.py")), ids=lambda p: p.name)
def test_the_grid_knows_nothing_of_cameras_stereo_sensor_models_or_files(path):
    forbidden = _imported_subpackages(path) & set(GRID_MUST_NOT_IMPORT)
    assert not forbidden, f"grid/{path.name} imports prismap.{', prismap.'.join(sorted(forbidden))}"


def test_no_source_file_is_over_600_lines():
    long = {
        str(p.relative_to(SRC)): n
        for p in SRC.rglob("*.py")
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, f"source files over {MAX_LINES} lines: {long}"


@pytest.mark.parametrize("name", SUBPACKAGES)
def test_star_import_of_every_subpackage_gives_its_whole_all(name):
    namespace = {}
    exec(f"from prismap.{name} import *", namespace)
    module = importlib.import_module(f"prismap.{name}")
    public = getattr(module, "__all__", None)
    assert public is not None, f"prismap.{name} has no __all__"
    assert len(set(public)) == len(public), f"prismap.{name}.__all__ repeats a name"
    assert set(public) <= set(namespace)


def test_the_version_has_one_source_and_the_typing_marker_ships():
    pyproject = tomllib.loads((SRC.parents[1] / "pyproject.toml").read_text(encoding="utf-8"))
    assert prismap.__version__ == pyproject["project"]["version"]
    assert (SRC / "py.typed").is_file()
    assert "py.typed" in pyproject["tool"]["setuptools"]["package-data"]["prismap"]
    assert (SRC.parents[1] / "LICENSE").read_text(encoding="utf-8").startswith("BSD 3-Clause License")
