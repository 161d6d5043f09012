"""Sphinx configuration of the stt-drake documentation (``make docs``).

Pages are Markdown (MyST-Parser); the API reference comes from the docstrings (autodoc,
napoleon for their Google-style sections); the scenario reference and the module lists are
generated from the code by the directives of ``docs/_ext/stt_docs.py``.
"""

import sys
from importlib.metadata import version as installed_version
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent / "_ext"))

project = "stt-drake"
author = "the stt-drake authors"
copyright = "2025-2026, the stt-drake authors"
release = installed_version("stt-drake")
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "stt_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build"]
myst_enable_extensions = ["dollarmath", "deflist"]
myst_heading_anchors = 3

# Docstrings: Google style; the signature's type hints are shown in the description.
napoleon_google_docstring = True
napoleon_numpy_docstring = False
autodoc_typehints = "description"
autodoc_member_order = "bysource"
# Members are chosen by where they are defined, not by a module's __all__ (which may
# re-export a name documented at its home).
autodoc_default_options = {"members": True, "ignore-module-all": True}

html_theme = "furo"
html_title = f"stt-drake {release}"
