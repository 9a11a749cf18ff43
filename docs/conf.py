"""Sphinx configuration of veil's documentation site (`make docs`).

Sphinx rather than MkDocs: the pages are Markdown already and MyST reads them unchanged,
autodoc/autosummary document the public API from the docstrings the code has, and
sphinx-gallery runs the examples and keeps their figures when the site is built. `-W` turns
every warning (a broken internal link, a missing page, a bad docstring) into an error.
"""

from __future__ import annotations

import os
import sys
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))

project = "veil"
author = "The veil maintainers"
copyright = "2026, The veil maintainers"
try:
    release = _version("veil")
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
templates_path = ["_templates"]

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


# Most docstrings are plain text written for `help()` and the terminal (formulas, aligned
# lists), not reStructuredText. A docstring that docutils cannot read cleanly as rst is shown
# as it is written, in a literal block under its first line, instead of as broken markup
# (which -W would turn into an error). Sphinx's own roles (:func:, :class:) are not problems.
def _rst_problems(text: str) -> list[str]:
    import io
    import re

    from docutils.core import publish_doctree

    text = re.sub(r":[\w:+-]+:`([^`]*)`", r"``\1``", text)  # Sphinx's roles need Sphinx
    stream = io.StringIO()
    try:
        publish_doctree(text, settings_overrides={
            "report_level": 2, "halt_level": 5, "warning_stream": stream})
    except Exception as exc:  # noqa: BLE001 - anything docutils cannot read is a problem
        return [repr(exc)]
    return [line for line in stream.getvalue().splitlines()
            if re.search(r"\((WARNING/2|ERROR/3|SEVERE/4)\)", line)
            and "Unknown interpreted text role" not in line and "No role entry" not in line
            and "Unknown directive type" not in line]


def _plain_docstrings(app, what, name, obj, options, lines):
    import inspect

    if not lines or not _rst_problems("\n".join(lines)):
        return
    doc = inspect.getdoc(obj) or ""
    first, _, rest = doc.strip().partition("\n\n")
    if _rst_problems(first):  # even the first paragraph: all of it as written
        first, rest = "", doc.strip()
    lines[:] = [" ".join(first.split()), ""] if first else []
    if rest.strip():
        lines += ["::", ""] + ["    " + line for line in rest.splitlines()] + [""]


def setup(app):
    app.connect("autodoc-process-docstring", _plain_docstrings, priority=900)
