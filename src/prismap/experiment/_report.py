"""The demo's report: ``index.html`` (figures inline, Markdown tables as HTML tables, one section per step
with its headline numbers) and the same content as ``index.md``. Links are relative, so the output folder
can be moved or served as it is."""

import html
import os
import re
from pathlib import Path

IMAGE_SUFFIXES = (".png", ".svg", ".jpg")
TABLE_SUFFIXES = (".md",)

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 2em; border-bottom: 1px solid #bbb; }
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


def format_index_html(sections, timings, out_dir, *, quick):
    """The HTML report: per section, its headline numbers, figures as ``<img>``, Markdown tables read from
    their files and shown as HTML tables, other files as links; every path relative to ``out_dir``."""
    out_dir = Path(out_dir)
    body = ["<h1>prismap demo</h1>"]
    if quick:
        body.append(f"<p><strong>{html.escape(QUICK_NOTE)}</strong></p>")
    body.append(f"<p>{html.escape(_run_time(timings))}</p>")
    body.append("<nav><ul>" + "".join(f'<li><a href="#s{i}">{html.escape(s.title)}</a></li>'
                                     for i, s in enumerate(sections)) + "</ul></nav>")
    for i, section in enumerate(sections):
        body.append(f'<section id="s{i}"><h2>{html.escape(section.title)}</h2>')
        if section.headline:
            body.append('<ul class="headline">' + "".join(f"<li>{_inline(n)}</li>" for n in section.headline) + "</ul>")
        for path, caption in section.items:
            link = html.escape(_relative(path, out_dir), quote=True)
            caption_html = _inline(caption)
            suffix = Path(path).suffix.lower()
            if suffix in IMAGE_SUFFIXES:
                body.append(f'<figure><img src="{link}" alt="{html.escape(caption, quote=True)}" loading="eager">'
                            f'<figcaption>{caption_html} (<a href="{link}">{link}</a>)</figcaption></figure>')
            elif suffix in TABLE_SUFFIXES and Path(path).is_file():
                body.append(f'<div class="table"><p class="caption">{caption_html} (<a href="{link}">{link}</a>)</p>'
                            f"{markdown_to_html(Path(path).read_text(encoding='utf-8'))}</div>")
            else:
                body.append(f'<p class="caption"><a href="{link}">{link}</a>: {caption_html}</p>')
        body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>prismap demo</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


_CELL_NUMBER = re.compile(r"^[-+]?(\*\*)?[-+]?[\d.,]+(e[-+]?\d+)?%?(\*\*)?$", re.IGNORECASE)


def markdown_to_html(text):
    """The Markdown the project writes (headings, paragraphs, ``-`` lists, pipe tables, ``**bold**``,
    ``code``) as HTML; headings are demoted below the report's ``<h2>``."""
    out, paragraph, rows, items = [], [], [], []

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
    numeric = [bool(body) and all(_CELL_NUMBER.match(r[j]) or r[j] in ("", "n/a") for r in body if j < len(r))
               for j in range(len(header))]

    def row_html(row, tag):
        return "<tr>" + "".join(f'<{tag}{" class=num" if j < len(numeric) and numeric[j] else ""}>{_inline(c)}</{tag}>'
                                for j, c in enumerate(row)) + "</tr>"

    return ("<table><thead>" + row_html(header, "th") + "</thead><tbody>"
            + "".join(row_html(r, "td") for r in body) + "</tbody></table>")


def _inline(text):
    """Escape ``text`` and render ``**bold**`` and ```code```."""
    text = html.escape(text)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
