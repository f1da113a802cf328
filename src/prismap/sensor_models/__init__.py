"""Inverse sensor models: measured disparities in, per-cell occupancy posteriors out (SENSOR_MODELS.md 4-5)."""

from prismap.sensor_models._base import (
    InverseSensorModel,
    error_model_use,
    make_sensor_model,
    model_defaults,
    model_names,
    register_model,
)
from prismap.sensor_models._classic import AndertModel, ConvolutionModel, HitMissModel, IdealModel
from prismap.sensor_models._conditioned import (
    CLASS_PASS_THROUGH,
    ConditionedModel,
    conditioned_sensor_model,
    model_for_mixture,
)
from prismap.sensor_models._failure import (
    blend_increments,
    evidence_bound,
    failure_floor,
    log_failure_posterior,
)
from prismap.sensor_models._prism import PrismModel
from prismap.sensor_models._prism_discrete import log_mean_likelihood, prism_discrete_posteriors
from prismap.sensor_models._prism_prior import estimate_prior_from_likelihood, prior_from_ground_truth
from prismap.sensor_models._table_store import STORE_ENV, TableStore, flush_table_stores, store_directory, table_store

__all__ = [
    "CLASS_PASS_THROUGH",
    "AndertModel",
    "ConditionedModel",
    "ConvolutionModel",
    "HitMissModel",
    "IdealModel",
    "InverseSensorModel",
    "STORE_ENV",
    "PrismModel",
    "TableStore",
    "blend_increments",
    "conditioned_sensor_model",
    "error_model_use",
    "estimate_prior_from_likelihood",
    "evidence_bound",
    "failure_floor",
    "flush_table_stores",
    "log_failure_posterior",
    "log_mean_likelihood",
    "make_sensor_model",
    "model_defaults",
    "model_for_mixture",
    "model_names",
    "prior_from_ground_truth",
    "prism_discrete_posteriors",
    "register_model",
    "store_directory",
    "table_store",
]
