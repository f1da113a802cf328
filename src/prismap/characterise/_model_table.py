"""The Markdown table of an error model: every fitted G with AIC/BIC, the selected one, and each class."""

from __future__ import annotations

from prismap.characterise._class_model import _describe
from prismap.characterise._features import FEATURE_UNITS
from prismap.characterise._model import HELD_OUT, ErrorModel

TABLE_MIN_WEIGHT = 0.1


def format_table(model: ErrorModel) -> str:
    """Markdown table of the fits in the layout of the thesis's tables 3.1-3.3.

    One row per G with AIC, BIC and ``mu, sigma, w`` per component, heaviest component first. Like the
    thesis, rows with more than three components list only the components with weight > 0.1 (the
    rest are summed in a note); the selected G is marked. A conditioned model adds a per-class table:
    each class's bounds, share of pixels, bad-2px rate and selected mixture, and the held-out
    log-likelihoods that chose the classes.
    """
    stats = model.statistics
    lines = [
        f"# Disparity error model: {model.matcher} on {model.dataset}",
        "",
        (
            f"Errors e = d_true - d_computed (px): {stats.get('n_errors', '?')} from {stats.get('n_frames', '?')} "
            f"frame(s); coverage {_percent(stats.get('coverage'))}, bad-1px {_percent(stats.get('bad_1px'))}, "
            f"bad-2px {_percent(stats.get('bad_2px'))}, mean |e| {_decimal(stats.get('mean_abs_error_px'))} px; "
            f"histogram bin width {model.bin_width:g} px."
        ),
        "",
        (
            f"Selected G = {model.selected_components} (marked *): " + _selection_rule(model.selection) + " "
            "AIC = 2k - 2 ln L and BIC = k ln N - 2 ln L with k = 3G - 1 (the thesis printed 2G as the AIC "
            f"penalty), 3G with a failure component. Rows with G > 3 list only components with weight > "
            f"{TABLE_MIN_WEIGHT}, as in the thesis."
        ),
        "",
    ]
    failures = model.mixture.search_range_px is not None
    if failures:
        lo, hi = model.mixture.search_range_px
        lines += [
            (
                f"Matcher failures: a component uniform over the search range {lo:g}..{hi:g} px (W = {hi - lo:g} "
                "px) in every mixture; w_f is its weight, the weights w of the Gaussians are among themselves "
                "(docs/SENSOR_MODELS.md section 8)."
            ),
            "",
        ]
    shown = []
    for fit in model.fits:
        components = _components(fit.mixture)
        if fit.n_components > 3:
            components = [c for c in components if c[2] > TABLE_MIN_WEIGHT]
        shown.append((fit, components))
    width = max(len(components) for _, components in shown)
    header = (
        ["G", "AIC", "BIC"]
        + (["w_f"] if failures else [])
        + [f"{s}{j + 1}" for j in range(width) for s in ("µ", "σ", "w")]
    )
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    notes = []
    for fit, components in shown:
        mark = "*" if fit.n_components == model.selected_components else ""
        cells = [f"{fit.n_components}{mark}", f"{fit.aic:.6g}", f"{fit.bic:.6g}"]
        cells += [f"{fit.mixture.failure_weight:.1e}"] if failures else []
        for mu, sigma, weight in components:
            cells += [f"{mu:.2f}", f"{sigma:.2f}", f"{weight:.2f}"]
        cells += [""] * (len(header) - len(cells))
        lines.append("| " + " | ".join(cells) + " |")
        hidden = fit.n_components - len(components)
        if hidden:
            rest = 1.0 - sum(c[2] for c in components)
            notes.append(
                f"G = {fit.n_components}: {hidden} component(s) with weight <= {TABLE_MIN_WEIGHT} "
                f"(together {rest:.2f}) not shown."
            )
    return "\n".join(lines + ([""] + notes if notes else []) + _class_lines(model)) + "\n"


def _selection_rule(selection):
    """How G was selected, in words."""
    if selection.get("criterion") == HELD_OUT:
        return (
            f"the G with the highest log-likelihood of held-out errors ({selection.get('held_out', '?')}), "
            "as for each class."
        )
    return (
        f"the smallest G whose {selection.get('criterion', 'bic').upper()} is within "
        f"{selection.get('tolerance_nats_per_error', 0)} nats per error of the best."
    )


def _class_lines(model):
    """The per-class view: bounds, share, bad pixels and the selected mixture of each class."""
    record = model.class_selection
    lines = []
    if record:
        lines += [
            "",
            "## Error classes",
            "",
            (
                f"Chosen by held-out log-likelihood ({record.get('held_out', '?')}): plain "
                f"{_decimal(record.get('plain_nats_per_error'))} nats per error, chosen classes "
                f"{_decimal(record.get('conditioned_nats_per_error'))} nats per error over "
                f"{record.get('n_held_out_errors', '?')} held-out errors."
            ),
        ]
    if not model.conditioned:
        return lines + (["", "The plain model predicts held-out errors best: one class."] if record else [])
    units = {name: FEATURE_UNITS[name] for name in model.classes.features}
    lines += [
        "",
        "Features: "
        + ", ".join(f"{name} ({unit})" for name, unit in units.items())
        + "."
        + (
            ' G "+ 1": the whole-image mixture\'s widest component mixed in with weight w.'
            if any(m.outlier is not None for m in model.class_models)
            else ""
        ),
        "",
    ]
    width = max(m.mixture.n_components for m in model.class_models)
    failures = model.mixture.search_range_px is not None
    header = (
        ["class", "bounds", "share", "bad-2px", "G"]
        + (["w_f"] if failures else [])
        + [f"{s}{j + 1}" for j in range(width) for s in ("µ", "σ", "w")]
    )
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for k, class_model in enumerate(model.class_models):
        cells = [
            str(k),
            _describe(model.classes, k),
            _percent(class_model.share),
            _percent(class_model.statistics.get("bad_2px")),
            str(class_model.selected_components)
            + ("" if class_model.outlier is None else f" + 1 (w {class_model.outlier['weight']:.1e})"),
        ]
        cells += [f"{class_model.mixture.failure_weight:.1e}"] if failures else []
        for mu, sigma, weight in _components(class_model.mixture):
            cells += [f"{mu:.2f}", f"{sigma:.2f}", f"{weight:.2f}"]
        cells += [""] * (len(header) - len(cells))
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _components(mixture):
    order = sorted(range(mixture.n_components), key=lambda j: -mixture.weights[j])
    return [(mixture.means[j], mixture.sigmas[j], mixture.weights[j]) for j in order]


def _percent(value):
    return "?" if value is None else f"{100 * value:.1f} %"


def _decimal(value):
    return "?" if value is None else f"{value:.3f}"
