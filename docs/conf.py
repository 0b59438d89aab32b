"""Sphinx configuration of the skcath documentation.

Build with (from the repository root)::

    .venv/bin/pip install -c constraints.txt -e ".[docs]"
    .venv/bin/python -m sphinx -b html docs docs/_build/html

The example gallery is built by sphinx-gallery from ``examples/``: scripts
whose name starts with ``plot_`` are executed and their figures embedded.
"""

import os
import sys
from datetime import date

# Import the package from the source tree even when it is not installed.
sys.path.insert(0, os.path.abspath(".."))

import skcath  # noqa: E402

project = "skcath"
author = "The skcath developers"
copyright = f"{date.today().year}, {author}"
version = ".".join(skcath.__version__.split(".")[:2])
release = skcath.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
]

templates_path = ["_templates"]
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
root_doc = "index"
default_role = "literal"

# -- autodoc / autosummary ---------------------------------------------------
autosummary_generate = True
# List only what a module exports in ``__all__``.
autosummary_ignore_module_all = False
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"

# -- numpydoc ----------------------------------------------------------------
# The class template lists members itself; numpydoc must not add a second
# table (and stub warnings) for them.
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = False

# -- sphinx-gallery ----------------------------------------------------------
from sphinx_gallery.sorting import ExplicitOrder  # noqa: E402

sphinx_gallery_conf = {
    "examples_dirs": "../examples",
    "gallery_dirs": "auto_examples",
    # Execute the scripts named plot_*.py; the others are only rendered.
    "filename_pattern": r"/plot_",
    "ignore_pattern": r"__init__\.py",
    # Topic sections in reading order: data, backbones, residuals, evaluation.
    "subsection_order": ExplicitOrder(
        [
            "../examples/datasets",
            "../examples/io",
            "../examples/backbones",
            "../examples/residuals",
            "../examples/model_selection",
            "../examples/online",
            "../examples/control",
        ]
    ),
    "within_subsection_order": "FileNameSortKey",
    "doc_module": ("skcath",),
    "backreferences_dir": os.path.join("gen_modules", "backreferences"),
    "reference_url": {"skcath": None},
    "download_all_examples": False,
    "remove_config_comments": True,
}

# -- HTML --------------------------------------------------------------------
html_theme = "alabaster"
html_static_path = ["_static"]
html_title = f"skcath {release}"
html_theme_options = {
    "description": "Catheter tip estimation from motor measurements",
    "fixed_sidebar": True,
}
