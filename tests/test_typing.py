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
    """(name, function, bound) of each public method, property getter and ``__init__`` that prismap defines on
    ``cls``; ``bound`` when its first parameter is ``self`` or ``cls``, which need no hint."""
    found = {}
    for klass in reversed(cls.__mro__):
        if not _is_prismap(klass):
            continue
        for name, member in vars(klass).items():
            if name.startswith("_") and name != "__init__":
                continue
            bound = not isinstance(member, staticmethod)
            if isinstance(member, property):
                member = member.fget
            elif isinstance(member, (staticmethod, classmethod)):
                member = member.__func__
            if inspect.isfunction(member) and _is_prismap(member):
                found[name] = (member, bound)
    return sorted((name, *entry) for name, entry in found.items())


def _public_callables():
    """(label, function, bound) of every public function and public method of ``prismap.__all__`` and every
    subpackage's ``__all__``."""
    found = {}
    for module in (prismap, *(importlib.import_module(f"prismap.{name}") for name in prismap._SUBPACKAGES)):
        for name in module.__all__:
            obj = getattr(module, name)
            if inspect.isclass(obj) and _is_prismap(obj):
                for method_name, method, bound in _public_methods(obj):
                    found.setdefault(f"{obj.__module__}.{obj.__qualname__}.{method_name}", (method, bound))
            elif callable(obj) and _is_prismap(obj) and not hasattr(obj, "py_func"):  # numba kernels stay bare
                function = inspect.unwrap(obj)
                found.setdefault(f"{function.__module__}.{function.__qualname__}", (function, False))
    return sorted((label, *entry) for label, entry in found.items())


PUBLIC = _public_callables()


def test_the_walk_finds_the_public_api():
    labels = {label for label, _, _ in PUBLIC}
    assert len(PUBLIC) > 300
    for expected in (
        "prismap.grid._map.OccupancyMap.__init__",
        "prismap.grid._map.OccupancyMap.known_voxels",  # a property
        "prismap.camera._stereo_camera.StereoCamera.from_kitti_projections",  # a classmethod
        "prismap.sim._textures.texture_bank",  # behind functools.lru_cache
        "prismap.cli._main.main",
        "prismap.sensor_models._base.register_model",  # its first parameter is a class, named cls, not bound
    ):
        assert expected in labels


@pytest.mark.parametrize("label, function, bound", PUBLIC, ids=[label for label, _, _ in PUBLIC])
def test_public_callable_is_annotated(label, function, bound):
    parameters = list(inspect.signature(function).parameters.values())[1 if bound else 0 :]
    missing = [parameter.name for parameter in parameters if parameter.annotation is inspect.Parameter.empty]
    assert not missing, f"{label}: parameters without a type hint: {missing}"
    assert inspect.signature(function).return_annotation is not inspect.Signature.empty, f"{label}: no return type hint"
    hints = typing.get_type_hints(function)  # raises NameError when a hint names what the module does not import
    assert set(hints) >= {parameter.name for parameter in parameters} | {"return"}
