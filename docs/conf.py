"""Sphinx configuration of bderiv's documentation site.

Build (warnings are errors, as in ``tests/test_docs_site.py``)::

    python -m sphinx -W -b html docs docs/_build/html
"""

import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent / "src"))  # the package of this checkout

project = "bderiv"
author = "the bderiv developers"
copyright = "2026, the bderiv developers"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "numpydoc",
    "bderiv_api",
]

root_doc = "index"
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_ext"]

# every cross-reference must resolve (unresolved Python names are looked up in the package
# by bderiv_api before they count as broken)
nitpicky = True
autodoc_typehints = "none"  # the types are in the numpydoc sections
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_validation_checks = set()

myst_heading_anchors = 4
myst_enable_extensions = ["dollarmath"]

html_theme = "pydata_sphinx_theme"
html_title = "bderiv"
html_theme_options = {"navigation_with_keys": False}
