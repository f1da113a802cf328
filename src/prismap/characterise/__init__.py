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
from prismap.characterise._histogram import ErrorHistogram
from prismap.characterise._model import ErrorModel, load_error_model, write_error_model
from prismap.characterise._model_table import format_table
from prismap.characterise._run import (
    Characterisation,
    characterise_matcher,
    write_characterisation,
)
from prismap.characterise._sample import PixelSample
from prismap.characterise._select import choose_classes

__all__ = [
    "FEATURE_UNITS",
    "NO_CLASS",
    "Characterisation",
    "ClassModel",
    "ErrorClasses",
    "ErrorCorrelation",
    "ErrorHistogram",
    "ErrorModel",
    "PixelFeatures",
    "PixelSample",
    "characterise_matcher",
    "choose_classes",
    "compute_features",
    "discontinuity_mask",
    "disparity_gradient",
    "format_table",
    "frame_error_correlation",
    "load_error_model",
    "write_characterisation",
    "write_error_model",
]
