"""MkDocs hook: the docstrings are written with Sphinx cross-reference roles (``:class:`~a.B```),
which Markdown shows literally; drop the role and the ``~`` so the reference reads as plain code."""
from __future__ import annotations

import re

_ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc|obj):(<code>)~?")


def on_page_content(html: str, **kwargs) -> str:
    return _ROLE.sub(r"\1", html)
