"""The must-shows of the conditioned error models, measured by the 3-D experiments themselves.

Each target states a claim about the results of one run, the numbers that decide it, and whether it is
met. The claims (issue 10): with SGBM and block matching, PRISM on the conditioned error model has the
lowest Brier score and log-loss of every model, the highest ROC AUC and a safety score no worse than
any other; on the street with SGBM it improves plain PRISM's log-loss by at least 10 %; and the
conditioned error model predicts held-out errors better than the plain one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prismap.characterise import ErrorModel
from prismap.experiment._results import CONDITIONED_SUFFIX, CellResult, model_label, split_variant

CHAMPION = "prism" + CONDITIONED_SUFFIX
"""The model the targets are about. Its rivals are every other model's cells; cells of the same model and error
model that differ only in their fusion (PRISM with the map as prior) are the claim's subject, not rivals."""
TARGET_MATCHERS = ("sgbm", "bm")
"""Matchers whose maps the ranking targets cover."""
LOG_LOSS_GAIN = {"street3d": ("sgbm", 0.10)}
"""World -> (matcher, least relative log-loss gain of conditioned over plain PRISM)."""
RANKED = (
    ("brier", "lowest Brier score", -1, True),
    ("log_loss", "lowest log-loss", -1, True),
    ("roc_auc", "highest ROC AUC", 1, True),
    ("safety_occupied_called_free", "safety score (occupied called free at 90 % free) no worse than", -1, False),
)
"""Scores ranked: (MapScores field, claim, +1 = higher is better / -1 = lower, strictly better needed)."""


@dataclass(frozen=True)
class Target:
    """One claim about a run, with the numbers that decide it.

    Attributes
    ----------
    claim : str
    measured : str
        The deciding numbers, in words.
    met : bool
    """

    claim: str
    measured: str
    met: bool

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form."""
        return {"claim": self.claim, "measured": self.measured, "met": self.met}


def measure_targets(
    world: str,
    results: Sequence[CellResult],
    error_models: Mapping[str, ErrorModel],
    mapped_likelihoods: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[Target]:
    """The targets of a 3-D run on ``world``.

    Parameters
    ----------
    world : str
        ``"scene3d"`` or ``"street3d"``.
    results : sequence of CellResult
    error_models : dict of str -> ErrorModel
        Each matcher's characterised error model (its ``class_selection`` holds the held-out
        log-likelihoods, nats per error, of the plain and the chosen conditioned model).
    mapped_likelihoods : dict of str -> dict or None
        Per matcher, the same on the mapping frames' errors (``conditioned_nats_per_error``,
        ``plain_nats_per_error``, ``n_errors``: ``mapped_log_likelihood`` of :mod:`prismap.experiment._scene3d`).

    Returns
    -------
    list of Target
        Only claims the run can decide (a matcher or model not run gives none).
    """
    targets = []
    for matcher in TARGET_MATCHERS:
        cells = {r.model: r.scores for r in results if r.matcher == matcher}
        if CHAMPION not in cells or len(cells) < 2:
            continue
        names = set(cells)
        for field, claim, sign, strict in RANKED:
            mine = getattr(cells[CHAMPION], field)
            others = {m: getattr(s, field) for m, s in cells.items() if split_variant(m) != split_variant(CHAMPION)}
            rival = max(others, key=lambda m: sign * others[m])
            met = bool(sign * mine > sign * others[rival] if strict else sign * mine >= sign * others[rival])
            said = f"a {claim} any other model's" if not strict else f"the {claim} of every model"
            targets.append(
                Target(
                    f"{world}, {matcher}: {model_label(CHAMPION)} has {said}",
                    f"{mine:.4f} against {others[rival]:.4f} for the best other ({model_label(rival, names)})",
                    met,
                )
            )
    if world in LOG_LOSS_GAIN:
        matcher, gain = LOG_LOSS_GAIN[world]
        cells = {r.model: r.scores for r in results if r.matcher == matcher}
        if CHAMPION in cells and "prism" in cells:
            plain, mine = cells["prism"].log_loss, cells[CHAMPION].log_loss
            measured_gain = (plain - mine) / plain
            targets.append(
                Target(
                    f"{world}, {matcher}: conditioned PRISM's log-loss at least {gain:.0%} below plain PRISM's",
                    f"{mine:.4f} against {plain:.4f}: {measured_gain:+.1%}",
                    bool(measured_gain >= gain),
                )
            )
    for matcher, model in error_models.items():
        targets.append(held_out_target(f"{world}, {matcher}", model))
    for matcher, mapped in (mapped_likelihoods or {}).items():
        conditioned, plain = mapped["conditioned_nats_per_error"], mapped["plain_nats_per_error"]
        targets.append(
            Target(
                f"{world}, {matcher}: log-likelihood of the mapping frames' errors higher conditioned than plain",
                f"{conditioned:.4f} against {plain:.4f} nats per error ({mapped['n_errors']} errors)",
                bool(conditioned > plain),
            )
        )
    return targets


def held_out_target(where, error_model):
    """The target "held-out errors are likelier under the conditioned error model than the plain one"."""
    chosen = error_model.class_selection
    plain = chosen.get("plain_nats_per_error", np.nan)
    conditioned = chosen.get("conditioned_nats_per_error", np.nan)
    return Target(
        f"{where}: held-out log-likelihood of the errors higher conditioned than plain",
        f"{conditioned:.4f} against {plain:.4f} nats per error ({error_model.n_classes} classes, "
        f"{chosen.get('n_held_out_errors', 0)} held-out errors)",
        bool(conditioned > plain),
    )


def format_targets(targets):
    """Markdown section: one line per target, its numbers and MET / NOT MET."""
    lines = ["## Targets", ""]
    if not targets:
        return "\n".join(lines + ["No target applies to this run (no conditioned PRISM, SGBM or BM cell).", ""])
    lines += ["| target | measured | |", "|---|---|---|"]
    lines += [f"| {t.claim} | {t.measured} | {'MET' if t.met else '**NOT MET**'} |" for t in targets]
    met = sum(t.met for t in targets)
    lines += ["", f"{met} of {len(targets)} targets met.", ""]
    return "\n".join(lines)
