"""Sphinx configuration of veil's documentation site (`make docs`).

Sphinx rather than MkDocs: the pages are Markdown already and MyST reads them unchanged,
autodoc/autosummary document the public API from the docstrings the code has, and
sphinx-gallery runs the examples and keeps their figures when the site is built. `-W` turns
every warning (a broken internal link, a missing page, a bad docstring) into an error.
"""

from __future__ import annotations

import os
import sys
from importlib.metadata import PackageNotFoundError, version

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))

project = "veil"
author = "The veil maintainers"
copyright = "2026, The veil maintainers"
try:
    release = version("veil")
except PackageNotFoundError:
    release = "0+unknown"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.json", "auto_examples/*.md5"]
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

html_theme = "furo"
html_title = f"veil {release}"
html_static_path = []

autosummary_generate = True
autodoc_typehints = "none"
autodoc_default_options = {"members": False}
napoleon_numpy_docstring = True
napoleon_google_docstring = False

# The examples: files named plot_*.py run when the site is built (their figures are made
# then); the longer ones are shown with their code and not run.
sphinx_gallery_conf = {
    "examples_dirs": os.path.join(HERE, "..", "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
}
