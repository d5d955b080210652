"""What a pull request changes, file by file: a line diff for text files, sizes for binary and LFS ones."""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field

from hub_envs.server.storage import Commit, FileEntry, Repo

MAX_TEXT_BYTES = 256 * 1024  # each side of a text diff: at most this large, else sizes only
MAX_LINES = 2000  # diff lines shown per file
MAX_TOTAL_LINES = 10_000  # diff lines shown per pull request (files past it show sizes)


@dataclass
class FileChange:
    """One changed file.

    Attributes:
        path: its path.
        status: ``added``, ``deleted`` or ``modified``.
        old: its entry before (None when added).
        new: its entry after (None when deleted).
        lines: the diff as ``(kind, text)`` rows, ``kind`` one of ``hunk``, ``add``, ``del``, ``ctx``; empty when
            no text diff is shown (see ``why``).
        why: why there is no text diff (binary, LFS, too large, identical text), or None.
        cut: the diff was longer than shown.
    """

    path: str
    status: str
    old: FileEntry | None
    new: FileEntry | None
    lines: list[tuple[str, str]] = field(default_factory=list)
    why: str | None = None
    cut: bool = False


def changes(repo: Repo, base: Commit, head: Commit) -> list[FileChange]:
    """The files ``head`` changes from ``base``, with text diffs while the total stays under :data:`MAX_TOTAL_LINES`.

    Args:
        repo: the repo both commits are in.
        base: where the pull request started.
        head: its head.

    Returns:
        One :class:`FileChange` per added, deleted or modified file, by path.
    """
    out = []
    budget = MAX_TOTAL_LINES
    for path in sorted(set(base.files) | set(head.files)):
        old, new = base.files.get(path), head.files.get(path)
        if old == new:
            continue
        status = "added" if old is None else "deleted" if new is None else "modified"
        change = FileChange(path, status, old, new)
        if budget <= 0:
            change.why = "diff not shown: the pull request's diff is longer than this page shows"
        else:
            _text_diff(repo, change, min(MAX_LINES, budget))
            budget -= len(change.lines)
        out.append(change)
    return out


def _text(repo: Repo, entry: FileEntry | None) -> str | None:
    """The entry's text; "" for no entry; None when it is LFS, too large or binary."""
    if entry is None:
        return ""
    if entry.lfs or entry.size > MAX_TEXT_BYTES:
        return None
    with repo.open_blob(entry) as f:
        data = f.read(MAX_TEXT_BYTES + 1)
    if b"\x00" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _text_diff(repo: Repo, change: FileChange, limit: int) -> None:
    for entry in (change.old, change.new):
        if entry is not None and entry.lfs:
            change.why = "stored with Git LFS: sizes only"
            return
        if entry is not None and entry.size > MAX_TEXT_BYTES:
            change.why = f"larger than {MAX_TEXT_BYTES // 1024} KiB: sizes only"
            return
    old, new = _text(repo, change.old), _text(repo, change.new)
    if old is None or new is None:
        change.why = "binary: sizes only"
        return
    diff = difflib.unified_diff(old.splitlines(), new.splitlines(), lineterm="", n=3)
    for line in diff:
        if line.startswith(("---", "+++")) and not change.lines:
            continue  # the file header: the page names the file
        kind = "hunk" if line.startswith("@@") else "add" if line.startswith("+") else "del" if line.startswith("-") else "ctx"
        if len(change.lines) >= limit:
            change.cut = True
            break
        change.lines.append((kind, line[:1000]))
    if not change.lines and not change.cut:
        change.why = "same text (whitespace at the end of the file only)" if old != new else "same content"
