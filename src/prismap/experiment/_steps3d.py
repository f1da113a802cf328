"""The steps of a 3-D experiment run, each resumable: match frames, characterise a matcher, derive PRISM's
parameters from the characterisation frames, and the map of each sensor model."""

import math
from pathlib import Path

from prismap._progress import progress
from prismap.experiment._results import (
    split_variant,
    variant_params,
)


def matcher_for(name, largest_disparity_px):
    """``name`` with a disparity range covering the largest true disparity of the scene."""
    from prismap.stereo import make_matcher

    if name == "variational":
        return make_matcher(name, max_disparity=float(math.ceil(largest_disparity_px) + 1))
    return make_matcher(name, num_disparities=16 * math.ceil((largest_disparity_px + 1) / 16))


def characterise_frames(out_dir, frames, matcher, dataset, *, source="ground-truth"):
    """The matcher's error mixture (characterised once, then read back) and its table and figures; ``source``
    says what the frames' ``disparity_gt`` is (see :func:`prismap.characterise.characterise_matcher`)."""
    from prismap.characterise import characterise_matcher, load_error_model, write_characterisation
    from prismap.characterise._run import written_characterisation

    paths = written_characterisation(out_dir)
    if paths is None:
        # the class search samples every frame: classes chosen on a subset of the street's frames predicted the
        # mapping frames' errors worse (README, conditioned error models)
        characterisation = characterise_matcher(
            frames, matcher, dataset=dataset, search_frames=len(frames), source=source
        )
        paths = write_characterisation(characterisation, out_dir)
    name = matcher.name
    artifacts = [
        (
            paths["table"],
            f"{name}: fitted error mixtures G = 1..4 with AIC/BIC, coverage, bad-1px, bad-2px "
            "(thesis tables 3.1-3.3 layout).",
        ),
        (paths["figure"], f"{name}: disparity error histogram with the fitted mixtures."),
        (paths["figure_wide"], f"{name}: the error tails on a log scale."),
        (paths["model"], f"{name}: the error model (JSON) every model of this matcher used."),
    ]
    return load_error_model(paths["model"]), artifacts


def read_disparities(disparity_dir, n_frames):
    """The matcher's disparity (pixels, NaN = invalid) of frames ``0 .. n_frames - 1`` from ``disparity_dir``."""
    from prismap.io import read_kitti_disparity

    for index in range(n_frames):
        yield read_kitti_disparity(Path(disparity_dir) / f"{index:06d}.png")


def match_frames(out_dir, frames, matcher):
    """Write the matcher's disparity of each of ``frames`` as ``NNNNNN.png`` (uint16, value / 256 px, 0 = invalid)."""
    from prismap.io import write_disparity_png

    out_dir = Path(out_dir)
    for index, frame in enumerate(progress(frames, total=len(frames), desc=f"match {matcher.name}", unit="frame")):
        path = out_dir / f"{index:06d}.png"
        if not path.is_file():
            write_disparity_png(
                path, matcher.compute(frame.left, frame.right), f"{matcher.name} disparity of frame {index}"
            )
    return out_dir


def derived_model_params(settings, scene, char_frames):
    """The run's model parameters, PRISM's ``pass_through`` and ``solid_depth_m`` measured on ``char_frames``
    unless the settings set them."""
    params = {name: dict(values) for name, values in settings["model_params"].items()}
    prism = params.setdefault("prism", {})
    if "pass_through" not in prism:
        prism["pass_through"] = scene.pass_through_ratio(
            char_frames, settings["voxel_size_m"], max_depth_m=settings["max_range_m"], subsample=settings["subsample"]
        )
    if "solid_depth_m" not in prism:
        prism["solid_depth_m"] = scene.solid_depth(
            char_frames, settings["voxel_size_m"], max_depth_m=settings["max_range_m"], subsample=settings["subsample"]
        )
    return params


def class_model_params(model_params, settings, scene, char_frames, error_model, disparity_dir):
    """``model_params`` with PRISM's ``class_pass_through`` for a conditioned ``error_model`` (unless the settings
    set it): the pass-through ratio of the rays of each class of the matcher's disparity of ``char_frames``
    (``disparity_dir``, see :func:`match_frames`), measured as the whole ratio is."""
    from prismap.sensor_models import CLASS_PASS_THROUGH

    prism = model_params["prism"]
    if not error_model.conditioned or CLASS_PASS_THROUGH in prism:
        return model_params
    labels = [
        error_model.classify_frame(frame.left, frame.right, disparity)
        for frame, disparity in zip(char_frames, read_disparities(disparity_dir, len(char_frames)))
    ]
    ratios = scene.pass_through_ratio(
        char_frames,
        settings["voxel_size_m"],
        max_depth_m=settings["max_range_m"],
        subsample=settings["subsample"],
        ray_classes=labels,
        n_classes=error_model.n_classes,
    )
    return dict(model_params, prism=dict(prism, **{CLASS_PASS_THROUGH: [float(m) for m in ratios]}))


def mapper(sequence, disparity_dir, matcher_name, error_model, p0, model_params, settings, *, error_model_path=None):
    """``build_map(cell_model)``: the pipeline's map of the mapping frames from the matcher's disparities.

    ``model_params``: model name -> its parameters (the settings' with what the run derived). With
    ``error_model_path`` (the file ``error_model`` was read from), ``build_map.record(cell_model, map_path)``
    writes ``MAP.run.json`` beside a cell's map: the ``prismap map`` command that makes it again.

    ``cell_model`` is a model name, plain, or with :data:`~prismap.experiment.CONDITIONED_SUFFIX`: conditioned
    on the error model's classes (plain when the characterisation chose none; PRISM then takes
    ``class_pass_through`` when ``model_params`` has it), then optionally
    :data:`~prismap.experiment.MAP_PRIOR_SUFFIX`: PRISM with the map as prior.
    """
    from prismap.pipeline import MappingConfig, map_sequence
    from prismap.sensor_models import CLASS_PASS_THROUGH

    def config_of(cell_model):
        model_name, conditioned = split_variant(cell_model)
        params = {**model_params.get(model_name, {}), **variant_params(cell_model)}
        if params.get("prior") == "map":  # PRISM's solid depth is a p0-prior model only
            params.pop("solid_depth_m", None)
        if not conditioned:  # one pass-through per error class is for conditioned PRISM
            params.pop(CLASS_PASS_THROUGH, None)
        config = MappingConfig(
            model=model_name,
            model_params=params,
            voxel_size_m=settings["voxel_size_m"],
            p0=p0,
            error_model=error_model,
            conditioned=None if conditioned else False,
            matcher=matcher_name,
            disparity_source=str(Path(disparity_dir).resolve()),
            max_range_m=settings["max_range_m"],
            subsample=settings["subsample"],
            mode=settings["mode"],
        )
        return config

    def build_map(cell_model):
        return map_sequence(sequence, config_of(cell_model))

    def record(cell_model, map_path):
        from prismap.cli._map import map_command, write_map_record

        config = config_of(cell_model)
        command = map_command(
            config,
            inputs=["--sequence", str(Path(sequence.path).resolve())],
            error_model=Path(error_model_path).resolve(),
            out=Path(map_path).resolve(),
        )
        write_map_record(map_path, command, config)

    if error_model_path is not None:
        build_map.record = record
    return build_map
