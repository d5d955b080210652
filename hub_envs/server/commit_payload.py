"""A commit's NDJSON body, as huggingface_hub sends it, read line by line into a store :class:`Change`;
and the rule commits to env repos are checked against (no compiled bytecode).

The body is cut into lines on the event loop (:func:`ndjson_lines`, each line capped); the lines are parsed,
decoded and their blobs written in a worker thread (:class:`CommitBuilder`), a large file's base64 in 1 MiB
pieces, so other requests keep being served during a big upload.
"""

from __future__ import annotations

import binascii
import json
import re
from collections.abc import AsyncIterator, Callable, Iterator, Mapping
from typing import Any

from starlette.requests import Request

from hub_envs.server.formats import ENV_MANIFEST
from hub_envs.server.httputil import BODY_SETTING, HTTPError, MiB, format_limit, too_large
from hub_envs.server.storage import (
    AddFile,
    Change,
    DeleteFile,
    DeleteFolder,
    FileEntry,
    InvalidOperationError,
    ParentMismatchError,
    Repo,
    validate_path,
)

#: The default cap (MiB) of one line of a commit body. A line carries one file inline, base64-encoded (4/3 of
#: its size), and is held in memory while it is stored. Only "regular" files come inline: /preupload sends every
#: file over 10 MiB (lfs.LFS_SIZE_THRESHOLD), and every binary one, through Git LFS, so huggingface_hub's
#: largest line is a 10 MiB text file: 13.3 MiB of base64 plus its path.
DEFAULT_MAX_LINE_MB = 16.0
LINE_SETTING = "--max_line_mb / HUB_ENVS_SERVER_MAX_LINE_MB"
_LINE_LIMIT = (
    f"the limit of one commit line, i.e. one inline file in base64 ({LINE_SETTING}); files over 10 MiB go through "
    "Git LFS, as huggingface_hub sends them when /preupload says so"
)
_B64_PIECE = MiB  # base64 decoded this much at a time: the GIL is released between pieces
_BIG_LINE = MiB  # lines over this size get the fast path of _parse_line


class CommitBuilder:
    """The lines of one commit payload, applied in order in a worker thread: the header (and its
    ``parentCommit`` check, before any blob is written), then each operation, its blob stored.

    Args:
        repo: the repo committed to; blobs are written into it as their lines arrive.
        branch: the branch (or ``refs/pr/N``) the commit goes to.
        check_parent: refuse a ``parentCommit`` that is not the branch's head (412) before any blob is written;
            off for ``create_pr``, where ``parentCommit`` is where the pull request starts.
    """

    def __init__(self, repo: Repo, branch: str, check_parent: bool = True):
        self.repo = repo
        self.branch = branch
        self.check_parent = check_parent
        self.header: dict | None = None
        self.operations: list = []

    def change(self, author: str, check: Callable[[Mapping[str, FileEntry]], None] | None) -> Change:
        """The commit the lines fed so far describe.

        Args:
            author: the account committing.
            check: called with the new tree before anything is written (see :class:`~hub_envs.server.storage.Change`).

        Returns:
            The :class:`~hub_envs.server.storage.Change` to apply.

        Raises:
            HTTPError: 400 for an empty body, an empty summary, or a summary or description that is not text.
        """
        header = self.header
        if header is None:
            raise HTTPError(400, "Malformed commit payload: empty body; send a 'header' line then the operations.")
        title = header.get("summary")
        if not isinstance(title, str) or not title.strip():
            raise HTTPError(400, "The commit summary (commit_message) cannot be empty.")
        description = header.get("description") or ""
        if not isinstance(description, str):
            raise HTTPError(400, "The commit description must be a string.")
        for text in (title, description):
            if not _is_unicode(text):
                raise HTTPError(400, "The commit summary and description must be valid Unicode (no lone surrogates).")
        return Change(
            self.operations, title=title, message=description, author=author, parent=header.get("parentCommit"), check=check
        )

    def feed(self, lines: list[bytearray]) -> None:
        """Parse and apply ``lines`` (emptied as they are applied), in order.

        Args:
            lines: the lines, as :func:`ndjson_lines` yields them.

        Raises:
            HTTPError: 400 for a malformed line, an invalid path or content, an LFS object never uploaded.
            ParentMismatchError: the header's ``parentCommit`` is not the branch's head (``check_parent``).
        """
        while lines:
            line = lines.pop(0)  # dropped once parsed: a big line is not kept alive by the list
            item, content = _parse_line(line)
            del line
            self._apply(item, content)

    def _apply(self, item: Any, content: memoryview | None) -> None:
        if not isinstance(item, dict) or "key" not in item or "value" not in item:
            raise HTTPError(400, 'Malformed commit payload: each line must be {"key": ..., "value": ...}.')
        key, value = item["key"], item["value"]
        if self.header is None:
            if key != "header" or not isinstance(value, dict):
                raise HTTPError(400, "Malformed commit payload: the first line must be the 'header'.")
            parent = value.get("parentCommit")
            if parent is not None:
                if not isinstance(parent, str) or not re.fullmatch(r"[0-9a-fA-F]{5,40}", parent):
                    raise HTTPError(400, f"Invalid parentCommit {parent!r}: expected 5 to 40 hex digits.")
                if self.check_parent and not self.repo.resolve(self.branch).id.startswith(parent.lower()):  # before any blob
                    raise ParentMismatchError("The branch was updated since you opened this page. Please refresh and try again.")
            self.header = value
            return
        if not isinstance(value, dict) or not isinstance(value.get("path"), str):
            raise HTTPError(400, f"Malformed commit payload: a {str(key)[:50]!r} line needs a 'path'.")
        path = value["path"]
        if key == "file":
            validate_path(path)
            self.operations.append(AddFile(path, self._store_file(path, value, content)))
        elif key == "lfsFile":
            validate_path(path)
            oid, size = value.get("oid", ""), value.get("size")
            if value.get("algo", "sha256") != "sha256":
                raise HTTPError(400, f"Unsupported LFS algo {str(value.get('algo'))[:20]!r} for {path!r}: expected 'sha256'.")
            have = self.repo.blob_size(oid) if isinstance(oid, str) else None
            if have is None:
                raise HTTPError(
                    400,
                    f"LFS object {str(oid)[:64]} for {path!r} was never uploaded to {self.repo.repo_id}: upload it through "
                    "the LFS batch API (.git/info/lfs/objects/batch) before the commit; huggingface_hub's create_commit "
                    "does so (re-run it). Nothing was committed.",
                    "LfsObjectMissing",
                )
            if size is not None and size != have:
                raise HTTPError(400, f"LFS object {oid} for {path!r} is {have} bytes on this server, not {size}.")
            self.operations.append(AddFile(path, self.repo.blob_entry(oid, lfs=True)))
        elif key == "deletedFile":
            self.operations.append(DeleteFile(path))
        elif key == "deletedFolder":
            self.operations.append(DeleteFolder(path.rstrip("/")))
        else:
            raise HTTPError(
                400,
                f"Malformed commit payload: unknown key {str(key)[:50]!r} (expected file, lfsFile, deletedFile, deletedFolder).",
            )

    def _store_file(self, path: str, value: dict, content: memoryview | None):
        encoding = value.get("encoding", "utf-8")
        if content is None:
            text = value.pop("content", "")
            if not isinstance(text, str):
                raise HTTPError(400, f"Malformed commit payload: the content of {path!r} must be a string.")
            if encoding != "base64":
                if not _is_unicode(text):
                    raise HTTPError(400, f"Malformed commit payload: the content of {path!r} is not valid Unicode.")
                return self.repo.write_blob(text.encode("utf-8"))
            try:
                content = memoryview(text.encode("ascii"))
            except UnicodeEncodeError:
                content = None
            del text
            if content is None:
                raise HTTPError(400, f"Malformed commit payload: the content of {path!r} is not valid base64.")
        size, pieces = _b64_pieces(content)
        if size is None:
            raise HTTPError(400, f"Malformed commit payload: the content of {path!r} is not valid base64.")
        try:
            return self.repo.write_blob_chunks(pieces, size)
        except (binascii.Error, ValueError):
            raise HTTPError(400, f"Malformed commit payload: the content of {path!r} is not valid base64.") from None


async def ndjson_lines(request: Request, max_body: int, max_line: int) -> AsyncIterator[list[bytearray]]:
    """The non-blank lines of an NDJSON body, as they arrive: one list per chunk that ends lines.

    Only cuts lines (a search in each new chunk, never in what is buffered already), so it is cheap
    on the event loop. 413 as soon as the body passes ``max_body`` or a line passes ``max_line``.

    Args:
        request: the request whose body to read.
        max_body: the body's cap in bytes.
        max_line: one line's cap in bytes.

    Yields:
        Lists of lines (``bytearray``, blank lines dropped).

    Raises:
        HTTPError: 413 naming the limit passed.
    """
    line = bytearray()
    total = 0
    async for chunk in request.stream():
        total += len(chunk)
        if total > max_body:
            raise too_large(max_body, f"the request body limit of this server ({BODY_SETTING})")
        done: list[bytearray] = []
        start = 0
        while True:
            i = chunk.find(b"\n", start)
            if i < 0:
                break
            line += chunk[start:i]
            if len(line) > max_line:
                raise too_large(max_line, _LINE_LIMIT)
            if line and not line.isspace():
                done.append(line)
            line = bytearray()
            start = i + 1
        line += chunk[start:]
        if len(line) > max_line:
            raise too_large(max_line, _LINE_LIMIT)
        if done:
            yield done
    if line and not line.isspace():
        yield [line]


def _loads_line(data) -> Any:
    try:
        return json.loads(data)
    except RecursionError:
        raise HTTPError(400, "Malformed commit payload: a line is nested too deeply.") from None
    except (ValueError, TypeError):  # JSONDecodeError, UnicodeDecodeError
        raise HTTPError(400, 'Malformed commit payload: each line must be {"key": ..., "value": ...}.') from None


_AFTER_CONTENT_KEY = re.compile(rb'\s*:\s*"')
_PLACEHOLDER = "\x00hub-envs:content"
_FIND_WINDOW = 8 * MiB


def _find(buf: bytearray, sub: bytes, start: int, end: int | None = None) -> int:
    """``buf.find(sub, start, end)`` a window at a time, so the GIL is released between windows."""
    end = len(buf) if end is None else end
    while start < end:
        stop = min(start + _FIND_WINDOW + len(sub) - 1, end)
        i = buf.find(sub, start, stop)
        if i >= 0:
            return i
        start += _FIND_WINDOW
    return -1


def _parse_line(line: bytearray) -> tuple[Any, memoryview | None]:
    """One commit line as JSON; for a large line, also the base64 content of its file, apart.

    A line of at most 1 MiB is parsed whole. A larger one must be a ``file`` line with base64
    content (the only line the client makes large): ``json.loads`` on hundreds of MiB would hold
    the GIL, stalling every other request, for seconds, and copy the content twice. So its
    ``"content": "..."`` string is cut out, the small rest parsed (with a placeholder in its
    place, which must land at ``value.content`` and nowhere else), and the content returned as a
    view of the line, to be decoded in pieces.
    """
    if len(line) <= _BIG_LINE:
        return _loads_line(line), None
    pos = 0
    for _ in range(4):  # the first few '"content"' in the line
        i = _find(line, b'"content"', pos)
        if i < 0:
            break
        pos = i + 1
        match = _AFTER_CONTENT_KEY.match(line, i + len(b'"content"'))
        if not match:
            continue
        start = match.end()
        end = _find(line, b'"', start)
        if end < 0:
            break
        if len(line) - (end - start) > _BIG_LINE:
            continue  # the rest of the line is large too: not the layout of a file line
        content: memoryview | bytes = memoryview(line)[start:end]
        if _find(line, b"\\", start, end) >= 0:  # some JSON encoders write "/" as "\/"; base64 has no other escape
            content = bytes(content).replace(b"\\/", b"/")
            if b"\\" in content:
                continue
        rest = bytes(line[:start]) + b"\\u0000hub-envs:content" + bytes(line[end:])
        item = _loads_line(rest)
        value = item.get("value") if isinstance(item, dict) else None
        if (
            isinstance(value, dict)
            and item.get("key") == "file"
            and value.get("encoding") == "base64"
            and value.get("content") == _PLACEHOLDER
            and _count_strings(item, _PLACEHOLDER) == 1
        ):
            del value["content"]
            return item, memoryview(content)
    raise HTTPError(
        400,
        f"Malformed commit payload: a line over {format_limit(_BIG_LINE)} must be a 'file' line with its content "
        'in base64 ({"key": "file", "value": {"content": "<base64>", "path": ..., "encoding": "base64"}}), '
        "as huggingface_hub sends it.",
    )


def _count_strings(obj: Any, needle: str) -> int:
    count, stack = 0, [obj]
    while stack:
        o = stack.pop()
        if isinstance(o, str):
            count += o == needle
        elif isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, list):
            stack.extend(o)
    return count


def _b64_pieces(encoded: memoryview) -> tuple[int | None, Iterator[bytes]]:
    """``(size, pieces)``: the decoded size of strict base64 ``encoded`` and its decoded pieces,
    1 MiB of input at a time (``binascii.Error`` from the iterator if invalid); size None if the
    length cannot be base64."""
    n = len(encoded)
    if n % 4:
        return None, iter(())
    pad = 0
    if n:
        pad = (encoded[-1] == 0x3D) + (encoded[-1] == 0x3D and encoded[-2] == 0x3D)

    def pieces() -> Iterator[bytes]:
        for i in range(0, n, _B64_PIECE):
            piece = encoded[i : i + _B64_PIECE].tobytes()
            if i + _B64_PIECE < n and b"=" in piece:
                raise binascii.Error("Padding before the end")
            yield binascii.a2b_base64(piece, strict_mode=True)

    return n // 4 * 3 - pad, pieces()


def _is_unicode(text: str) -> bool:
    """False for text holding lone surrogates (JSON's ``"\\ud800"``), which cannot be UTF-8."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _is_bytecode(path: str) -> bool:
    """``.pyc``/``.pyo`` files and anything under a ``__pycache__/`` folder (any case, and with the
    trailing dots and spaces Windows drops from names)."""
    parts = [part.rstrip(" .").lower() for part in path.split("/")]
    return "__pycache__" in parts[:-1] or parts[-1].endswith((".pyc", ".pyo"))


def refuse_bytecode_in_env_repos(files: Mapping[str, FileEntry]) -> None:
    """The ``check`` of commits (see :meth:`~hub_envs.server.storage.Repo.commit`): no bytecode in an env repo's tree.

    An env repo (one with a ``hub_env.json`` manifest at its root) is loaded by importing its
    ``.py`` files; a ``__pycache__/*.pyc`` beside them would run instead of the sources that the
    manifest hashes and the card shows, so it can only be planted. Other repos may hold any file.

    Args:
        files: the new tree, path -> entry.

    Raises:
        InvalidOperationError: the tree is an env repo's and holds bytecode.
    """
    if ENV_MANIFEST not in files:
        return
    planted = sorted(p for p in files if _is_bytecode(p))
    if planted:
        more = f" (and {len(planted) - 1} more)" if len(planted) > 1 else ""
        raise InvalidOperationError(
            f"Refused: {planted[0]!r}{more} is compiled Python bytecode (under __pycache__/, or .pyc/.pyo) in an "
            f"env repo (one with {ENV_MANIFEST}). Python would run it instead of the .py sources, so an env repo "
            "holds sources only: leave bytecode out of the commit (or delete it in the same commit)."
        )
