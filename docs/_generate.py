"""Pages generated when the site is built: the CLI reference from the argument parser, and the results tables
from the experiment runs' ``results.json`` files (``docs/results/*.json``)."""

import argparse
import json
import os
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def write_all(folder):
    """Write ``cli-reference.md`` and ``results-tables.md`` into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cli-reference.md").write_text(cli_reference(), encoding="utf-8")
    (folder / "results-tables.md").write_text(results_tables(RESULTS), encoding="utf-8")


def cli_reference():
    """Every ``prismap`` command's ``--help``, walked from :func:`prismap.cli._main.build_parser`."""
    from prismap.cli._main import build_parser

    os.environ["COLUMNS"] = "110"  # argparse wraps the help to this width
    lines = []
    for name, parser in _walk(build_parser(), ()):
        lines += [f"## `{' '.join(('prismap', *name))}`", "", "```text", parser.format_help().rstrip(), "```", ""]
    # included under cli.md's title: its headings are that page's sections
    return "\n".join(lines)


def _walk(parser, name):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child_name, child in action.choices.items():
                yield from _walk(child, (*name, child_name))


def results_tables(folder):
    """One table per ``results.json`` of ``folder``: every matcher x model with its scores and the run's settings."""
    from prismap.experiment._results import RESULTS_FORMAT, format_results_table, read_results

    lines = []
    for path in sorted(folder.glob("*.json")):
        document = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(document, dict) or document.get("format") != RESULTS_FORMAT:
            continue  # another kind of JSON kept beside the runs
        settings = document.get("settings", {})
        shown = ", ".join(f"{k} = {settings[k]}" for k in ("n_frames", "voxel_size_m", "subsample", "matchers")
                          if k in settings)
        table = format_results_table(read_results(path), title=document.get("title", path.stem),
                                     notes=(f"From `docs/results/{path.name}` ({shown}).",))
        lines.append(table.replace("\n# ", "\n### ").replace("# ", "### ", 1))
    return "\n".join(lines) if lines else "No results files in `docs/results/`.\n"
