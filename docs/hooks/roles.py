"""MkDocs hook: Sphinx cross-reference roles in docstrings (``:func:`fk```) render as plain code.

The docstrings use Sphinx's roles, which mkdocstrings leaves in the HTML (``:func:<code>fk</code>``,
``:class:<code>~diffkin.Robot</code>``); this hook removes the role and the ``~``.
"""

import re

_ROLE = re.compile(r":(?:py:)?(?:func|class|meth|attr|mod|data|obj|exc|const):<code>~?")


def on_page_content(html: str, **kwargs) -> str:
    """The page's HTML without role prefixes in front of inline code."""
    return _ROLE.sub("<code>", html)
