"""A griffe extension (``mkdocs.yml`` names it): the docstrings' Sphinx roles as Markdown code on the API page.

The package's docstrings name other objects the Sphinx way (``:func:`hub_envs.load_env```, ``:class:`~x.Y```), which
reads well in ``help()``; mkdocstrings renders Markdown, where they would show as raw roles.
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const):`(~?)([^`]+)`")


def _code(match: re.Match) -> str:
    tilde, target = match.groups()
    return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"  # ~a.b.C shows as C, as Sphinx does


class SphinxRolesAsCode(griffe.Extension):
    """Rewrite ``:role:`target``` in every docstring as `` `target` ``."""

    def on_object(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = ROLE.sub(_code, obj.docstring.value)
