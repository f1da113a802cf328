"""Inverse sensor models: measured disparities in, per-cell occupancy posteriors out (SENSOR_MODELS.md 4-5)."""

from prismap.sensor_models._base import (
    POLICIES,
    InverseSensorModel,
    make_sensor_model,
    model_names,
    register_model,
)

__all__ = ["POLICIES", "InverseSensorModel", "make_sensor_model", "model_names", "register_model"]
