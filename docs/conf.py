"""Sphinx configuration of prismap's documentation site (``make docs``).

Pages are the Markdown files of ``docs/`` (MyST), the API reference comes from the numpydoc docstrings,
the gallery runs ``docs/examples/plot_*.py`` at build time, and two pages are generated here before the
build: the CLI reference (walking the ``prismap`` argument parser) and the results tables (from the
experiment runs' ``results.json`` files in ``docs/results/``).
"""

import os
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # _generate.py

import _generate  # noqa: E402

from prismap import __version__  # noqa: E402

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PRISMAP_PROGRESS", "0")

project = "prismap"
author = "prismap developers"
copyright = "prismap developers"
version = release = __version__

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
# the generated pages are included by cli.md and results.md; the gallery's sources are read by sphinx-gallery
exclude_patterns = ["_build", "results", "examples", "_generated/cli-reference.md", "_generated/results-tables.md"]
root_doc = "index"

myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3
suppress_warnings = ["myst.xref_missing"]  # links to source files and folders outside the site stay as text

templates_path = ["_templates"]  # autosummary: one page per class and function of each subpackage
autosummary_generate = True
autosummary_imported_members = True   # the subpackages export what their private modules define
autosummary_ignore_module_all = False  # ... exactly what ``__all__`` lists
autodoc_default_options = {"members": True}
autodoc_typehints = "none"  # the numpydoc docstrings describe each type with its shape and unit; the hints are for tools
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
}

html_theme = "pydata_sphinx_theme"
html_title = "prismap"
html_static_path = []
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}

shutil.rmtree(HERE / "_generated" / "api", ignore_errors=True)  # stubs of objects that moved would stay behind
_generate.write_all(HERE / "_generated")
