"""Text from a repo or an endpoint, made safe to print.

Repo-controlled strings (file names, manifest fields, URLs and headers from an endpoint) can hold
terminal escape sequences or bidi overrides that rewrite what a user reads in an error message:

    >>> from hub_envs._text import safe_text
    >>> safe_text("dynamics.py")
    'dynamics.py'
"""

from __future__ import annotations

import re
from typing import Any

_NAMED_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t", "\\": "\\\\"}


def _escape_char(ch: str) -> str:
    if ch in _NAMED_ESCAPES:
        return _NAMED_ESCAPES[ch]
    o = ord(ch)
    return f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def safe_text(value: Any) -> str:
    """``value`` as text that is safe to print on a terminal, escaped the way ``repr`` escapes a string:
    every character ``str.isprintable`` rejects except the plain space (C0 and C1 controls, so ESC and
    CSI; DEL; bidi overrides and other format characters; line separators; lone surrogates) becomes
    ``\\x1b``, ``\\u202e``..., and a backslash becomes ``\\\\`` so an escape cannot be faked.

    Use it wherever a message interpolates repo-controlled text (file names, manifest fields, the
    dataset's metadata, text from the env's code).

    >>> safe_text("tiny.py"), safe_text("a\\x1b[2Jb.py"), safe_text("gpj.\\u202eexe")
    ('tiny.py', 'a\\\\x1b[2Jb.py', 'gpj.\\\\u202eexe')
    """
    text = value if isinstance(value, str) else str(value)
    if text.isprintable() and "\\" not in text:
        return text
    return "".join(ch if ch == " " or (ch.isprintable() and ch != "\\") else _escape_char(ch) for ch in text)


def safe_lines(value: Any) -> str:
    """:func:`safe_text` line by line: the line breaks stay, everything else is escaped (for multi-line text from
    an env's code: an exception message, a traceback, the tail of a worker's stderr).

    >>> safe_lines("line 1\\n\\x1b[31mred")
    'line 1\\n\\\\x1b[31mred'
    """
    text = value if isinstance(value, str) else str(value)
    return "\n".join(safe_text(line) for line in text.split("\n"))


def md_code(value: Any, *, table_cell: bool = True) -> str:
    """``value`` as one Markdown inline code span, whatever backticks it holds (a fence one longer than its longest run
    of them, padded when it starts or ends with one: CommonMark), on one line; in a table cell (``table_cell``) its
    ``|`` escaped, so the row keeps its cells (GitHub's tables take ``\\|`` as a literal pipe, in code spans too).

    >>> md_code("pick"), md_code("a`b"), md_code("`x|y`"), md_code("a|b", table_cell=False)
    ('`pick`', '``a`b``', '`` `x\\\\|y` ``', '`a|b`')
    """
    text = " ".join(str(value).split())
    fence = "`" * (max((len(run) for run in re.findall(r"`+", text)), default=0) + 1)
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    if table_cell:
        text = text.replace("|", "\\|")
    return f"{fence}{pad}{text}{pad}{fence}"
