"""The demo's report: ``index.html`` leads with the answer (which model wins, PRISM against OctoMap, the maps),
then every step's numbers, tables (folded) and figures; ``index.md`` links the same files. Images are embedded,
so the HTML file stands alone; other links are relative, so the output folder can be moved or served as it is."""

import base64
import html
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from prismap.evaluate import EXTREME_COLUMNS, SCORE_COLUMNS
from prismap.experiment._results import CONDITIONED_SUFFIX, best_models, cell_path, model_label

IMAGE_SUFFIXES = (".png", ".svg", ".jpg")
TABLE_SUFFIXES = (".md",)

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 2em; border-bottom: 1px solid #bbb; } h3 { margin-top: 1.5em; }
details { margin: 0.5em 0; } summary { cursor: pointer; color: #334; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.85em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; } th { background: #eee; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption, .caption { color: #555; font-size: 0.9em; } ul.headline li { margin: 0.2em 0; }
"""


def _relative(path, out_dir):
    return Path(os.path.relpath(path, out_dir)).as_posix()


def _run_time(timings):
    total = sum(timings.values())
    return f"Run time: {total:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")."


QUICK_NOTE = "Quick mode: tiny sizes that only show the pipeline runs; the numbers are not meaningful."


def format_index_markdown(sections, timings, out_dir, *, quick):
    """The Markdown index: per section, headline lines and links (relative to ``out_dir``) with captions."""
    lines = ["# prismap demo", ""]
    if quick:
        lines += [QUICK_NOTE, ""]
    lines += [_run_time(timings), ""]
    for section in sections:
        lines += [f"## {section.title}", ""]
        lines += [f"- {note}" for note in section.headline]
        if section.headline:
            lines.append("")
        for path, caption in section.items:
            link = _relative(path, out_dir)
            lines.append(f"- [{link}]({link}): {caption}")
        lines.append("")
    return "\n".join(lines)


@dataclass(frozen=True)
class Report:
    """What the HTML report is drawn from.

    Attributes
    ----------
    sections : sequence of Section
        The demo's steps in order (``title``, ``headline`` lines, ``(path, caption)`` items).
    timings : dict of str -> float
        Each step's wall time, seconds.
    out_dir : Path
        The report's folder; paths are shown relative to it.
    quick : bool
    experiments : dict of str -> ExperimentResult
        The experiment runs by world (``office2d``, ``scene3d``, ...), for the summary and the map links.
    render_3d : (Path, str) or None
        A 3-D figure of one map and its caption, shown at the top.
    shell_dir : str
        How the command line names ``out_dir`` (the demo's ``--out`` as given), for the ``prismap view``
        commands.
    embed : bool
        Images as ``data:`` URIs, so the file stands alone; else ``<img>`` links relative to ``out_dir``.
    """

    sections: tuple
    timings: dict
    out_dir: Path
    quick: bool = False
    experiments: dict = field(default_factory=dict)
    render_3d: tuple | None = None
    shell_dir: str = "outputs"
    embed: bool = True


def format_index_html(report):
    """The HTML report of ``report``: the answer first (:data:`REPORT_PARTS`), every table and figure below."""
    body = ["<h1>prismap demo</h1>"]
    if report.quick:
        body.append(f"<p><strong>{html.escape(QUICK_NOTE)}</strong></p>")
    body.append(f"<p>{html.escape(_run_time(report.timings))}</p>")
    for part in REPORT_PARTS:
        body += part(report)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>prismap demo</title>'
        f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


def _summary(report):
    """Which model wins on each world and matcher by each score (the better direction of each column)."""
    scores = [(label, name) for label, name, _, better in SCORE_COLUMNS if better is not None]
    rows = []
    for world, result in report.experiments.items():
        best = best_models(result.cells)
        names = {c.model for c in result.cells}
        for matcher in dict.fromkeys(c.matcher for c in result.cells):
            rows.append([world, matcher] + [_model_html(best.get((matcher, name)), names) for _, name in scores])
    if not rows:
        return []
    header = "".join(f"<th>{html.escape(h)}</th>" for h in ("world", "matcher", *(label for label, _ in scores)))
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return [
        '<section id="summary"><h2>Which model wins</h2>',
        "<p>The best model of each world and matcher on each score (lowest; highest for ROC AUC), over every "
        "model the run mapped; PRISM in bold.</p>",
        f"<table><thead><tr>{header}</tr></thead><tbody>{body}</tbody></table></section>",
    ]


def _model_html(model, names):
    if model is None:
        return "n/a"
    label = html.escape(model_label(model, names))
    return f"<strong>{label}</strong>" if model.startswith("prism") else label


HEADLINE_SCORES = ("brier", "log_loss", "roc_auc", "safety_occupied_called_free")
"""The scores of the PRISM-vs-OctoMap headline."""


def _prism_vs_octomap(report):
    """PRISM (conditioned where the run has it) against OctoMap's hit/miss model, per world and matcher."""
    columns = [(label, name, fmt) for label, name, fmt, _ in SCORE_COLUMNS if name in HEADLINE_SCORES]
    rows = []
    for world, result in report.experiments.items():
        names = {c.model for c in result.cells}
        prism = "prism" + CONDITIONED_SUFFIX if "prism" + CONDITIONED_SUFFIX in names else "prism"
        for matcher in dict.fromkeys(c.matcher for c in result.cells):
            cells = {c.model: c for c in result.cells if c.matcher == matcher}
            if prism not in cells or "hitmiss" not in cells:
                continue
            ours, theirs = cells[prism].scores, cells["hitmiss"].scores
            texts = [
                f"{fmt.format(getattr(ours, name))} vs {fmt.format(getattr(theirs, name))}" for _, name, fmt in columns
            ]
            rows.append([world, matcher, html.escape(model_label(prism, names)), *texts])
    if not rows:
        return []
    header = "".join(f"<th>{html.escape(h)}</th>" for h in ("world", "matcher", "PRISM", *(c[0] for c in columns)))
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return [
        '<section id="headline"><h2>PRISM against OctoMap</h2>',
        "<p>Each cell: PRISM vs OctoMap's hit/miss model on the same disparities and voxels (Brier score, "
        "log-loss and occupied called free at 90 % free: lower is better; ROC AUC: higher).</p>",
        f"<table><thead><tr>{header}</tr></thead><tbody>{body}</tbody></table></section>",
    ]


def _maps_at_a_glance(report):
    """The 3-D render of one map, then every map-slice figure of the runs."""
    parts = ['<section id="maps"><h2>The maps</h2>']
    if report.render_3d is not None:
        parts.append(_figure(report, *report.render_3d))
    for section in report.sections:
        for path, caption in section.items:
            if Path(path).name.startswith(("map_slices", "maps")) and Path(path).suffix.lower() in IMAGE_SUFFIXES:
                parts.append(_figure(report, path, caption))
    parts += _map_files(report)
    return parts + ["</section>"]


def _map_files(report):
    """Every map file of the runs, with the ``prismap view`` command that opens it beside its ground truth and,
    where the run wrote it, the ``prismap map`` command that makes it again (``MAP.run.json``)."""
    rows = []
    for world, result in report.experiments.items():
        truth = report.out_dir / world / "sequence" / "occupancy.npz"
        names = {c.model for c in result.cells}
        for cell in result.cells:
            path = cell_path(report.out_dir / world, cell.matcher, cell.model).with_suffix(".npz")
            if not path.is_file():
                continue
            command = f"prismap view {report.shell_dir}/{_relative(path, report.out_dir)}"
            if truth.is_file():
                command += f" --gt {report.shell_dir}/{_relative(truth, report.out_dir)}"
            record = path.with_suffix(".run.json")
            again = "" if not record.is_file() else _link(record, report.out_dir, "prismap map command")
            rows.append(
                f"<tr><td>{html.escape(world)}</td><td>{html.escape(cell.matcher)}</td>"
                f"<td>{html.escape(model_label(cell.model, names))}</td><td>{_link(path, report.out_dir)}</td>"
                f"<td><code>{html.escape(command)}</code></td><td>{again}</td></tr>"
            )
    if not rows:
        return []
    return [
        "<details><summary>Every map file, the command that opens it in the 3-D viewer and the one that makes "
        "it again</summary><table><thead><tr><th>world</th><th>matcher</th><th>model</th><th>map</th>"
        f"<th>open with</th><th>reproduce</th></tr></thead><tbody>{''.join(rows)}</tbody></table></details>"
    ]


def _link(path, out_dir, text=None):
    link = html.escape(_relative(path, out_dir), quote=True)
    return f'<a href="{link}">{html.escape(text) if text else link}</a>'


def _details(report):
    """Every step's headline numbers, tables and figures; tables folded, targets left out."""
    parts = [
        '<h2 id="details">Details</h2>',
        "<nav><ul>"
        + "".join(f'<li><a href="#s{i}">{html.escape(s.title)}</a></li>' for i, s in enumerate(report.sections))
        + "</ul></nav>",
    ]
    for i, section in enumerate(report.sections):
        parts.append(f'<section id="s{i}"><h3>{html.escape(section.title)}</h3>')
        if section.headline:
            parts.append(
                '<ul class="headline">' + "".join(f"<li>{_inline(n)}</li>" for n in section.headline) + "</ul>"
            )
        for path, caption in section.items:
            link = html.escape(_relative(path, report.out_dir), quote=True)
            suffix = Path(path).suffix.lower()
            if suffix in IMAGE_SUFFIXES:
                parts.append(_figure(report, path, caption))
            elif suffix in TABLE_SUFFIXES and Path(path).is_file():
                table = markdown_to_html(Path(path).read_text(encoding="utf-8"), skip=FOLDED_OUT)
                parts.append(
                    f'<details><summary>{_inline(caption)}</summary><p class="caption">'
                    f'<a href="{link}">{link}</a></p>{table}</details>'
                )
            else:
                parts.append(f'<p class="caption"><a href="{link}">{link}</a>: {_inline(caption)}</p>')
        parts.append("</section>")
    return parts


def _confident_and_wrong(report):
    """Per world and matcher, each model's "confident and wrong" rates (the extremes a planner trusts most)."""
    rows = []
    for world, result in report.experiments.items():
        names = {c.model for c in result.cells}
        for cell in result.cells:
            scores = cell.scores
            rows.append(
                [
                    html.escape(world),
                    html.escape(cell.matcher),
                    _model_html(cell.model, names),
                    *(_value_html(fmt, getattr(scores, name)) for _, name, fmt in EXTREME_COLUMNS),
                ]
            )
    if not rows:
        return []
    labels = ("world", "matcher", "model", *(label for label, *_ in EXTREME_COLUMNS))
    header = "".join(f"<th>{html.escape(h)}</th>" for h in labels)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return [
        '<section id="extremes"><h2>Confident and wrong</h2>',
        "<p>Truly free voxels a map puts at P &ge; 0.99 and truly occupied voxels at P &le; 0.01: where a "
        "planner trusts the map most, lower is better. A map that is never that sure scores 0 there, so the last "
        "two columns ask the calibrated question: of the voxels a map puts at P &ge; 0.99 (P &le; 0.01), how many "
        "are free (occupied)? A calibrated map keeps both at or below 1 %; &ndash; where it is never that sure. "
        "The reliability diagrams on log-odds axes and the per-frame evidence histograms (Details) show where "
        "they come from.</p>",
        f"<details><summary>Every map</summary><table><thead><tr>{header}</tr></thead><tbody>{body}</tbody>"
        "</table></details></section>",
    ]


def _value_html(fmt, value):
    """``value`` in ``fmt``, or an en dash when the map put no voxel there (NaN)."""
    return "&ndash;" if math.isnan(value) else fmt.format(value)


REPORT_PARTS = (_summary, _prism_vs_octomap, _confident_and_wrong, _maps_at_a_glance, _details)
"""The report's parts in order, each ``part(report) -> list of HTML strings``: a new section is one function
added here."""

FOLDED_OUT = ("Targets",)
"""Sections of the results files the report leaves out (the development targets stay in ``results.md``)."""


def _figure(report, path, caption):
    """``<figure>`` of an image, embedded as a ``data:`` URI when ``report.embed``, with a link to its file."""
    link = html.escape(_relative(path, report.out_dir), quote=True)
    source = link
    if report.embed and Path(path).is_file():
        kind = {".svg": "svg+xml", ".jpg": "jpeg"}.get(Path(path).suffix.lower(), "png")
        source = f"data:image/{kind};base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return (
        f'<figure><img src="{source}" alt="{html.escape(caption, quote=True)}" loading="eager">'
        f'<figcaption>{_inline(caption)} (<a href="{link}">{link}</a>)</figcaption></figure>'
    )


_CELL_NUMBER = re.compile(r"^[-+]?(\*\*)?[-+]?[\d.,]+(e[-+]?\d+)?%?(\*\*)?$", re.IGNORECASE)


def markdown_to_html(text, *, skip=()):
    """The Markdown the project writes (headings, paragraphs, ``-`` lists, pipe tables, ``**bold**``,
    ``code``) as HTML; headings are demoted below the report's ``<h2>``. A section whose heading starts
    with one of ``skip`` is left out, up to the next heading of its level or above."""
    out, paragraph, rows, items = [], [], [], []
    skipping = None  # the level of the heading being skipped

    def flush():
        if paragraph:
            out.append(f"<p>{_inline(' '.join(paragraph))}</p>")
            paragraph.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()
        if rows:
            out.append(_table(rows))
            rows.clear()

    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            if skipping is not None and level <= skipping:
                skipping = None
            if skipping is None and line.lstrip("#").strip().startswith(tuple(skip)):
                skipping = level
        if skipping is not None:
            continue
        if line.startswith("|"):
            if paragraph or items:
                flush()
            rows.append(line)
            continue
        if rows:
            flush()
        if not line:
            flush()
        elif line.startswith("#"):
            flush()
            level = min(len(line) - len(line.lstrip("#")) + 2, 6)
            out.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
        elif line.startswith(("- ", "* ")):
            if paragraph:
                flush()
            items.append(line[2:])
        else:
            paragraph.append(line)
    flush()
    return "\n".join(out)


def _table(rows):
    cells = [[c.strip() for c in row.strip().strip("|").split("|")] for row in rows]
    header, body = cells[0], cells[1:]
    if body and all(re.fullmatch(r":?-{3,}:?", c) for c in body[0]):
        body = body[1:]
    numeric = [
        bool(body) and all(_CELL_NUMBER.match(r[j]) or r[j] in ("", "n/a") for r in body if j < len(r))
        for j in range(len(header))
    ]

    def row_html(row, tag):
        return (
            "<tr>"
            + "".join(
                f"<{tag}{' class=num' if j < len(numeric) and numeric[j] else ''}>{_inline(c)}</{tag}>"
                for j, c in enumerate(row)
            )
            + "</tr>"
        )

    return (
        "<table><thead>"
        + row_html(header, "th")
        + "</thead><tbody>"
        + "".join(row_html(r, "td") for r in body)
        + "</tbody></table>"
    )


def _inline(text):
    """Escape ``text`` and render ``**bold**`` and ```code```."""
    text = html.escape(text)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
