"""The targets section of the 3-D experiments: each claim decided from the cells' scores, against hand-made tables."""

from types import SimpleNamespace

import pytest

from prismap.experiment import MODELS_3D, measure_targets
from prismap.experiment._results import MODELS_3D_MAP_PRIOR, model_label, split_variant, variant_params
from prismap.experiment._targets import format_targets


def cell(matcher, model, brier, log_loss, roc_auc, safety):
    scores = SimpleNamespace(brier=brier, log_loss=log_loss, roc_auc=roc_auc, safety_occupied_called_free=safety)
    return SimpleNamespace(matcher=matcher, model=model, scores=scores)


def error_model(plain, conditioned, n_classes):
    selection = {"plain_nats_per_error": plain, "conditioned_nats_per_error": conditioned, "n_held_out_errors": 500}
    return SimpleNamespace(class_selection=selection, n_classes=n_classes)


def test_variant_names_and_labels():
    assert split_variant("prism_conditioned") == ("prism", True) and split_variant("andert") == ("andert", False)
    assert model_label("prism_conditioned") == "prism (conditioned)"
    assert model_label("prism", MODELS_3D) == "prism (plain)" and model_label("hitmiss", MODELS_3D) == "hitmiss"
    assert model_label("prism", ("prism", "ideal")) == "prism"
    assert split_variant("prism_conditioned_map_prior") == ("prism", True)
    assert variant_params("prism_conditioned_map_prior") == {"prior": "map"} and variant_params("prism") == {}
    assert model_label("prism_conditioned_map_prior") == "prism (conditioned, map prior)"
    assert model_label("prism_map_prior", MODELS_3D_MAP_PRIOR) == "prism (map prior)"


def test_each_claim_is_decided_by_its_numbers():
    results = [
        cell("sgbm", "andert", 0.030, 0.120, 0.90, 0.40),
        cell("sgbm", "prism", 0.025, 0.110, 0.91, 0.30),
        cell("sgbm", "prism_conditioned", 0.024, 0.098, 0.90, 0.30),
        cell("bm", "prism", 0.03, 0.13, 0.88, 0.42),
        cell("bm", "prism_conditioned", 0.031, 0.12, 0.89, 0.41),
    ]
    models = {"sgbm": error_model(-0.80, -0.70, 5), "bm": error_model(-0.75, -0.75, 1)}
    targets = {t.claim: t for t in measure_targets("street3d", results, models)}
    met = {claim: t.met for claim, t in targets.items()}
    assert met == {
        "street3d, sgbm: prism (conditioned) has the lowest Brier score of every model": True,
        "street3d, sgbm: prism (conditioned) has the lowest log-loss of every model": True,
        "street3d, sgbm: prism (conditioned) has the highest ROC AUC of every model": False,  # 0.90 < 0.91
        "street3d, sgbm: prism (conditioned) has a safety score (occupied called free at 90 % free) no worse "
        "than any other model's": True,  # a tie is no worse
        "street3d, bm: prism (conditioned) has the lowest Brier score of every model": False,
        "street3d, bm: prism (conditioned) has the lowest log-loss of every model": True,
        "street3d, bm: prism (conditioned) has the highest ROC AUC of every model": True,
        "street3d, bm: prism (conditioned) has a safety score (occupied called free at 90 % free) no worse "
        "than any other model's": True,
        "street3d, sgbm: conditioned PRISM's log-loss at least 10% below plain PRISM's": True,  # 10.9 %
        "street3d, sgbm: held-out log-likelihood of the errors higher conditioned than plain": True,
        "street3d, bm: held-out log-likelihood of the errors higher conditioned than plain": False,  # equal
    }
    auc = targets["street3d, sgbm: prism (conditioned) has the highest ROC AUC of every model"]
    assert auc.measured == "0.9000 against 0.9100 for the best other (prism (plain))"
    gain = targets["street3d, sgbm: conditioned PRISM's log-loss at least 10% below plain PRISM's"]
    assert gain.measured == "0.0980 against 0.1100: +10.9%"
    text = format_targets(list(targets.values()))
    assert text.count("**NOT MET**") == 3 and "8 of 11 targets met." in text


@pytest.mark.parametrize("world", ["scene3d", "street3d"])
def test_a_run_without_conditioned_prism_decides_only_the_error_models(world):
    targets = measure_targets(world, [cell("sgbm", "prism", 0.02, 0.1, 0.9, 0.3)], {"sgbm": error_model(-1.0, -0.9, 3)})
    assert [t.claim for t in targets] == [
        f"{world}, sgbm: held-out log-likelihood of the errors higher conditioned than plain"
    ]
    assert "No target applies" in format_targets([])


def test_the_mapping_frames_likelihood_is_a_target_decided_by_its_numbers():
    mapped = {
        "sgbm": {"conditioned_nats_per_error": -0.40, "plain_nats_per_error": -0.52, "n_errors": 900},
        "bm": {"conditioned_nats_per_error": -0.94, "plain_nats_per_error": -0.54, "n_errors": 700},
    }
    targets = measure_targets("street3d", [], {}, mapped)
    assert [(t.claim, t.measured, t.met) for t in targets] == [
        (
            "street3d, sgbm: log-likelihood of the mapping frames' errors higher conditioned than plain",
            "-0.4000 against -0.5200 nats per error (900 errors)",
            True,
        ),
        (
            "street3d, bm: log-likelihood of the mapping frames' errors higher conditioned than plain",
            "-0.9400 against -0.5400 nats per error (700 errors)",
            False,
        ),
    ]


def test_the_champions_own_fusion_variant_is_not_its_rival():
    base = [
        cell("sgbm", "prism", 0.025, 0.110, 0.91, 0.30),
        cell("sgbm", "prism_conditioned", 0.024, 0.098, 0.90, 0.30),
    ]
    sibling = cell("sgbm", "prism_conditioned_map_prior", 0.001, 0.001, 0.99, 0.0)  # better on every score
    models = {"sgbm": error_model(-0.80, -0.70, 5)}
    alone = [(t.claim, t.measured, t.met) for t in measure_targets("scene3d", base, models)]
    assert [(t.claim, t.measured, t.met) for t in measure_targets("scene3d", [*base, sibling], models)] == alone
    rival = cell("sgbm", "andert", 0.001, 0.2, 0.5, 0.5)  # another model still is one
    assert not next(t for t in measure_targets("scene3d", [*base, rival], models) if "Brier" in t.claim).met
