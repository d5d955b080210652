"""Text from a repo or an endpoint, made safe to print.

Repo-controlled strings (file names, manifest fields, URLs and headers from an endpoint) can hold
terminal escape sequences or bidi overrides that rewrite what a user reads in an error message:

    >>> from hub_envs._text import printable
    >>> printable("evil\\x1b[2Jname\\u202e.py")
    'evil\\\\x1b[2Jname\\\\u202e.py'
    >>> printable("dynamics.py")
    'dynamics.py'
"""

from __future__ import annotations

import unicodedata


def printable(text: object) -> str:
    """``text`` with every control, format (bidi) and separator character other than a plain space escaped."""
    out = []
    for ch in str(text):
        if ch == " " or (ch.isprintable() and unicodedata.category(ch) not in ("Cf", "Zl", "Zp")):
            out.append(ch)
        else:
            out.append(ch.encode("unicode_escape").decode("ascii"))
    return "".join(out)
