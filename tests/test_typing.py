"""The public API is annotated (issue #23): every function and class a subpackage's ``__all__`` lists has type
hints on all its parameters and its return, and the hints resolve (``typing.get_type_hints``), so a new public
function without them fails here."""

import importlib
import inspect
import typing

import pytest

import prismap


def _is_prismap(obj):
    return getattr(obj, "__module__", "").startswith("prismap")


def _public_methods(cls):
    """(name, function) of each public method, property getter and ``__init__`` that prismap defines on ``cls``."""
    found = {}
    for klass in reversed(cls.__mro__):
        if not _is_prismap(klass):
            continue
        for name, member in vars(klass).items():
            if name.startswith("_") and name != "__init__":
                continue
            if isinstance(member, property):
                member = member.fget
            elif isinstance(member, (staticmethod, classmethod)):
                member = member.__func__
            if inspect.isfunction(member) and _is_prismap(member):
                found[name] = member
    return sorted(found.items())


def _public_callables():
    """(label, function) of every public function and public method of every subpackage's ``__all__``."""
    found = {}
    for package in prismap._SUBPACKAGES:
        module = importlib.import_module(f"prismap.{package}")
        for name in module.__all__:
            obj = getattr(module, name)
            if inspect.isclass(obj) and _is_prismap(obj):
                for method_name, method in _public_methods(obj):
                    found.setdefault(f"{obj.__module__}.{obj.__qualname__}.{method_name}", method)
            elif callable(obj) and _is_prismap(obj) and not hasattr(obj, "py_func"):  # numba kernels stay bare
                function = inspect.unwrap(obj)
                found.setdefault(f"{function.__module__}.{function.__qualname__}", function)
    return sorted(found.items())


PUBLIC = _public_callables()


def test_the_walk_finds_the_public_api():
    labels = {label for label, _ in PUBLIC}
    assert len(PUBLIC) > 300
    for expected in (
        "prismap.grid._map.OccupancyMap.__init__",
        "prismap.grid._map.OccupancyMap.known_voxels",  # a property
        "prismap.camera._stereo_camera.StereoCamera.from_kitti_projections",  # a classmethod
        "prismap.sim._textures.texture_bank",  # behind functools.lru_cache
        "prismap.cli._main.main",
    ):
        assert expected in labels


@pytest.mark.parametrize("label, function", PUBLIC, ids=[label for label, _ in PUBLIC])
def test_public_callable_is_annotated(label, function):
    signature = inspect.signature(function)
    missing = [
        name
        for name, parameter in signature.parameters.items()
        if name not in ("self", "cls") and parameter.annotation is inspect.Parameter.empty
    ]
    assert not missing, f"{label}: parameters without a type hint: {missing}"
    assert signature.return_annotation is not inspect.Signature.empty, f"{label}: no return type hint"
    hints = typing.get_type_hints(function)
    assert set(hints) >= {name for name in signature.parameters if name not in ("self", "cls")} | {"return"}
