"""Errors of a stereo matcher against ground truth, their histograms, fitted error models and tables."""

from prismap.characterise._class_model import ClassModel
from prismap.characterise._classes import NO_CLASS, ErrorClasses
from prismap.characterise._correlation import ErrorCorrelation, frame_error_correlation
from prismap.characterise._features import (
    FEATURE_UNITS,
    PixelFeatures,
    compute_features,
    discontinuity_mask,
    disparity_gradient,
)
from prismap.characterise._fusion import (
    FUSION_MODELS,
    fit_fusion,
    fusion_block,
    fusion_from_block,
    map_reading,
)
from prismap.characterise._histogram import ErrorHistogram
from prismap.characterise._model import ErrorModel, load_error_model, write_error_model
from prismap.characterise._model_table import format_table
from prismap.characterise._rig import RIG_RTOL, check_rig, describe_rig, rig_differences
from prismap.characterise._run import (
    Characterisation,
    characterise_matcher,
    write_characterisation,
)
from prismap.characterise._sample import PixelSample
from prismap.characterise._select import choose_classes
from prismap.characterise._self import SelfCharacterisation, lag_agreement, self_characterise

__all__ = [
    "FEATURE_UNITS",
    "FUSION_MODELS",
    "NO_CLASS",
    "RIG_RTOL",
    "Characterisation",
    "ClassModel",
    "ErrorClasses",
    "ErrorCorrelation",
    "ErrorHistogram",
    "ErrorModel",
    "PixelFeatures",
    "PixelSample",
    "SelfCharacterisation",
    "characterise_matcher",
    "check_rig",
    "choose_classes",
    "compute_features",
    "describe_rig",
    "discontinuity_mask",
    "disparity_gradient",
    "fit_fusion",
    "format_table",
    "lag_agreement",
    "frame_error_correlation",
    "fusion_block",
    "fusion_from_block",
    "map_reading",
    "load_error_model",
    "rig_differences",
    "self_characterise",
    "write_characterisation",
    "write_error_model",
]
