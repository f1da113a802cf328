"""The error-source comparison: per-class likelihoods against a per-pixel reference, and targets measured as stated."""

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel
from prismap.experiment._sources3d import _targets, class_log_likelihoods, format_sources
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.io import StereoFrame

CAMERA = StereoCamera(50.0, 15.5, 11.5, 0.2, width=32, height=24)


def _plain(sigma):
    mixture = GaussianMixture([0.9, 0.1], [0.0, 1.0], [sigma, 4.0])
    return ErrorModel("sgbm", {}, "test", 1 / 32, (MixtureFit(mixture, -1.0, 1.0, 1.0, 10.0, 1, True),), 2)


def test_class_log_likelihoods_match_a_pixel_by_pixel_sum():
    rng = np.random.default_rng(5)
    frames, disparities, expected = [], [], [0.0, 0.0]
    mine, theirs = _plain(0.3), _plain(0.6)
    for _ in range(2):
        truth = rng.uniform(5, 20, (CAMERA.height, CAMERA.width)).astype(np.float32)
        disparity = truth - rng.normal(0, 0.4, truth.shape)
        disparity[rng.random(truth.shape) < 0.2] = np.nan
        image = np.zeros(truth.shape, np.uint8)
        frames.append(StereoFrame(image, image, CAMERA, truth))
        disparities.append(disparity)
        for v in range(CAMERA.height):
            for u in range(CAMERA.width):
                if np.isfinite(disparity[v, u]):
                    e = float(truth[v, u]) - disparity[v, u]
                    expected[0] += float(mine.mixture.logpdf(np.array([e]))[0])
                    expected[1] += float(theirs.mixture.logpdf(np.array([e]))[0])
    rows = class_log_likelihoods(mine, theirs, frames, disparities)
    n = sum(int(np.isfinite(d).sum()) for d in disparities)
    assert rows[-1]["class"] == "all" and rows[-1]["n_errors"] == n == rows[0]["n_errors"]
    assert rows[-1]["model_nats_per_error"] == pytest.approx(expected[0] / n, rel=1e-9)
    assert rows[-1]["reference_nats_per_error"] == pytest.approx(expected[1] / n, rel=1e-9)
    assert rows[-1]["model_nats_per_error"] > rows[-1]["reference_nats_per_error"]  # sigma 0.3 fits 0.4 better


def _document(self_brier, self_moto_auc, lidar_gap):
    scores = {
        "brier": 0.10,
        "log_loss": 0.30,
        "ece": 0.02,
        "roc_auc": 0.90,
        "occupied_called_free": 0.2,
        "free_called_occupied": 0.05,
    }
    worse = dict(
        scores,
        brier=0.2,
        log_loss=0.6,
        ece=0.05,
        roc_auc=self_moto_auc,
        occupied_called_free=0.4,
        free_called_occupied=0.1,
    )
    cells = [
        {"matcher": "sgbm", "model": "prism", "source": "ground-truth", "scores": scores},
        {"matcher": "sgbm", "model": "prism", "source": "self", "scores": dict(scores, brier=self_brier)},
        {"matcher": "sgbm", "model": "prism", "source": "motorcycle", "scores": worse},
    ]
    ll = {"conditioned_nats_per_error": -1.0, "plain_nats_per_error": -1.1, "n_errors": 10}
    likelihood = {
        "sgbm": {
            "ground-truth": ll,
            "self": ll,
            "motorcycle": ll,
            "lidar": dict(ll, conditioned_nats_per_error=-1.0 - lidar_gap),
            "self_by_class": [
                {"class": "all", "n_errors": 10, "model_nats_per_error": -1.2, "reference_nats_per_error": -1.0}
            ],
        }
    }
    return {"world": "street3d", "p0": 0.1, "cells": cells, "likelihood": likelihood}


def test_targets_are_met_and_missed_as_measured():
    met = {t["target"]: t for t in _targets(_document(0.104, 0.5, 0.01))}
    assert all(t["met"] for t in met.values())
    assert met["sgbm prism: self brier within 5% of ground truth"]["value"] == pytest.approx(0.04)
    missed = {t["target"]: t for t in _targets(_document(0.106, 0.95, 0.08))}
    assert not missed["sgbm prism: self brier within 5% of ground truth"]["met"]
    assert missed["sgbm prism: self better than Motorcycle on every score"]["value"] == "roc_auc"
    lidar = next(t for t in missed.values() if "LiDAR" in t["target"])
    assert not lidar["met"] and lidar["value"] == pytest.approx(0.08)
    document = _document(0.106, 0.95, 0.08)
    document["targets"] = _targets(document)
    text = format_sources(document)
    assert "| sgbm | prism | self | 0.1060 |" in text and "| NO |" in text
