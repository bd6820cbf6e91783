"""Sphinx configuration of the positioning_cell docs (MyST Markdown; `make docs`, and
test/test_docs.py builds them with warnings as errors)."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE / '_ext'), str(HERE.parent)]

project = 'positioning_cell'
author = 'positioning_cell developers'
copyright = '2025, positioning_cell developers'
release = version = '0.1.0'

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.autosummary',
    'generated',  # docs/_ext/generated.py: the reference pages written from the code
]
# .rst: autosummary's stubs of the API pages.
source_suffix = {'.md': 'markdown', '.rst': 'restructuredtext'}
root_doc = 'index'
# The generated fragments are included by the reference pages, not pages of their own.
exclude_patterns = ['_build', 'reference/generated']

myst_heading_anchors = 3
myst_enable_extensions = ['colon_fence']

autosummary_generate = True
# A package page documents what its __init__ defines, not the functions it re-exports from its
# modules (documented there; some share their module's name).
autodoc_default_options = {'members': True, 'undoc-members': False, 'show-inheritance': True,
                           'ignore-module-all': True}
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'
autodoc_class_signature = 'separated'

html_theme = 'alabaster'
html_title = 'positioning_cell'


# The docstrings write norms as |Δp| and never use reStructuredText substitutions: a bar outside
# a literal is text, shown as U+2223 (the same width, so the docstrings' simple tables keep
# their columns).
_LITERAL = re.compile(r'(``.*?``|`[^`]*`)')


def _docstring_as_written(app: object, what: str, name: str, obj: object, options: object,
                          lines: list[str]) -> None:
    # A package's docstring names its modules relative to itself (:mod:`.settings`): made
    # absolute, as the summary tables show it outside the package's own page.
    if what == 'module' and hasattr(obj, '__path__'):
        lines[:] = [line.replace(':mod:`.', f':mod:`{name}.') for line in lines]
    for i, line in enumerate(lines):
        parts = _LITERAL.split(line)
        lines[i] = ''.join(p if j % 2 else p.replace('|', '\u2223') for j, p in enumerate(parts))


def setup(app: Any) -> None:
    app.connect('autodoc-process-docstring', _docstring_as_written)
