"""Git LFS in the loopback Hub server, as huggingface.co speaks it to ``huggingface_hub``: the preupload
rules (which files go through LFS), the batch API with basic and multipart transfers (signed upload URLs,
bytes streamed to disk and sha256-checked) and verify. The steps, in order: ``docs/server.md#git-lfs``.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import json
import logging
import math
import os
import re
import shutil
import threading
import time
from collections import OrderedDict
from typing import Any

from starlette.concurrency import run_in_threadpool
from starlette.responses import Response

from hub_envs.server.access import Access
from hub_envs.server.httputil import Ctx, HTTPError, body_json, call, json_response, limit_bytes, only, read_body, repo_url
from hub_envs.server.storage import Commit, HubStore, Repo

logger = logging.getLogger("hub_envs.server.lfs")

MiB = 1024 * 1024
#: Over this size a file goes through LFS whatever its name (the Hub's rule: 10 MB).
LFS_SIZE_THRESHOLD = 10 * MiB
DEFAULT_CHUNK_MB = 64.0
DEFAULT_MAX_LFS_MB = 50 * 1024.0  # the Hub's cap on one file: 50 GB
_CHUNK_SETTING = "HUB_ENVS_SERVER_LFS_CHUNK_MB"
_MAX_LFS_SETTING = "--max_lfs_mb / HUB_ENVS_SERVER_MAX_LFS_MB"
_URL_TTL = 24 * 3600
_FLUSH = 1 * MiB  # received bytes are written (and hashed, in a worker thread) this much at a time
_HASH_PIECE = 8 * MiB
_MAX_OBJECTS = 10_000  # per batch request (huggingface_hub sends at most 256)
_MAX_PARTS = 10_000
_OID_RE = re.compile(r"[0-9a-f]{64}")
_LFS_JSON = "application/vnd.git-lfs+json"
_GITATTRIBUTES_MAX = 1 * MiB  # read this much of a .gitattributes at most
_GITATTRIBUTES_MAX_PATTERNS = 10_000
_NO_XET = (
    "This Hub (hub-envs serve) stores large files through Git LFS, not Xet. huggingface_hub >= 1.0 uploads through Xet "
    "whenever the hf_xet package is installed: set HF_HUB_DISABLE_XET=1 in the client's environment (hub-envs' own "
    "push_env does it itself for repos that are not Xet-enabled)."
)


# --- the preupload rules -----------------------------------------------------------------------


def _pattern_regex(pattern: str) -> re.Pattern | None:
    """A ``.gitattributes`` pattern as a regex on the repo path (gitignore's matching rules):
    without a ``/`` it matches the file name at any depth; with one, the path from the root,
    ``**`` spanning folders."""
    anchored = "/" in pattern.rstrip("/")
    pattern = pattern.lstrip("/")
    out, i, n = [], 0, len(pattern)
    while i < n:
        c = pattern[i]
        if pattern.startswith("**/", i):
            out.append("(?:.*/)?")
            i += 3
        elif pattern.startswith("/**", i) and i + 3 == n:
            out.append("/.*")
            i += 3
        elif pattern.startswith("**", i):
            out.append(".*")
            i += 2
        elif c == "*":
            out.append("[^/]*")
            i += 1
        elif c == "?":
            out.append("[^/]")
            i += 1
        elif c == "[":
            j = pattern.find("]", i + 2)
            if j < 0:
                out.append(re.escape(c))
                i += 1
                continue
            body = pattern[i + 1 : j]
            if body.startswith("!"):
                body = "^" + body[1:]
            out.append("[" + body.replace("\\", "\\\\") + "]")
            i = j + 1
        else:
            out.append(re.escape(c))
            i += 1
    regex = "".join(out)
    try:
        return re.compile(regex if anchored else f"(?:.*/)?{regex}", re.S)
    except re.error:
        return None


def parse_gitattributes(text: str) -> list[tuple[re.Pattern, bool]]:
    """``(pattern, lfs)`` rules of a ``.gitattributes``, in order (the last match wins): ``lfs`` is
    True for ``filter=lfs``, False for ``-filter``, ``!filter`` or another filter.

    Args:
        text: the file's text.

    Returns:
        ``(regex, lfs)`` pairs; malformed lines and patterns are skipped (at most 10,000 rules).
    """
    rules: list[tuple[re.Pattern, bool]] = []
    for line in text.splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#") or parts[0].startswith("!") or len(parts[0]) > 1024:
            continue
        verdict = None
        for attr in parts[1:]:
            if attr == "filter=lfs":
                verdict = True
            elif attr in ("-filter", "!filter") or attr.startswith("filter="):
                verdict = False
        if verdict is None:
            continue
        regex = _pattern_regex(parts[0])
        if regex is not None:
            rules.append((regex, verdict))
        if len(rules) >= _GITATTRIBUTES_MAX_PATTERNS:
            break
    return rules


def is_binary(sample: bytes) -> bool:
    """The Hub's test on a file's first 512 bytes: a NUL byte, or bytes that are not UTF-8 (a
    character cut at the end of the sample does not count).

    Args:
        sample: the file's first bytes.
    """
    if b"\x00" in sample:
        return True
    try:
        sample.decode("utf-8")
    except UnicodeDecodeError as err:
        return not (err.reason == "unexpected end of data" and err.start >= len(sample) - 3)
    return False


def upload_mode(rules: list[tuple[re.Pattern, bool]], path: str, size: int, sample: bytes) -> str:
    """``"lfs"`` or ``"regular"`` for a file of ``size`` bytes starting with ``sample``, by the Hub's rules.

    Args:
        rules: the repo's ``.gitattributes`` rules (:func:`parse_gitattributes`).
        path: the file's path in the repo.
        size: its size in bytes.
        sample: its first 512 bytes.
    """
    if size == 0:
        return "regular"  # an empty file is never LFS (the client sends it inline whatever the answer)
    for regex, lfs in reversed(rules):
        if regex.fullmatch(path):
            if lfs:
                return "lfs"
            break
    if size > LFS_SIZE_THRESHOLD or is_binary(sample):
        return "lfs"
    return "regular"


# --- the routes ------------------------------------------------------------------------------


class LfsRoutes:
    """The LFS routes: preupload decisions, the batch API, uploads, verify.

    Args:
        store: the repos.
        access: who may write where.
        max_lfs_mb: largest LFS file in MiB (default 51200; env ``HUB_ENVS_SERVER_MAX_LFS_MB``).
        chunk_mb: part size of multipart uploads in MiB (default 64; env ``HUB_ENVS_SERVER_LFS_CHUNK_MB``).

    Raises:
        ValueError: a limit is not a positive number.
    """

    def __init__(self, store: HubStore, access: Access, *, max_lfs_mb: float | None = None, chunk_mb: float | None = None):
        self.store = store
        self.access = access
        self.max_object = limit_bytes(max_lfs_mb, "HUB_ENVS_SERVER_MAX_LFS_MB", DEFAULT_MAX_LFS_MB, "max_lfs_mb")
        self.chunk_size = limit_bytes(chunk_mb, _CHUNK_SETTING, DEFAULT_CHUNK_MB, "lfs chunk_mb")
        self._secret = os.urandom(32)
        self._rules: OrderedDict[str, list] = OrderedDict()  # .gitattributes sha256 -> rules
        self._rules_guard = threading.Lock()
        self._told_xet = False
        self._swept = 0.0

    # -- preupload --

    def _rules_for(self, repo: Repo, commit: Commit) -> list[tuple[re.Pattern, bool]]:
        entry = commit.files.get(".gitattributes")
        if entry is None:
            return []
        with self._rules_guard:
            if entry.sha256 in self._rules:
                return self._rules[entry.sha256]
        with repo.open_blob(entry) as f:
            text = f.read(_GITATTRIBUTES_MAX).decode("utf-8", "replace")
        rules = parse_gitattributes(text)
        with self._rules_guard:
            self._rules[entry.sha256] = rules
            while len(self._rules) > 256:
                self._rules.popitem(last=False)
        return rules

    def preupload_answer(self, repo: Repo, commit: Commit, item: dict) -> dict:
        """The preupload answer for one ``{path, size, sample}`` of the request (path already validated).

        Args:
            repo: the repo uploaded to.
            commit: the revision uploaded to (its ``.gitattributes`` and files).
            item: one entry of the request's ``files``.

        Returns:
            ``{path, uploadMode, shouldIgnore, oid}``, as the Hub answers it.

        Raises:
            HTTPError: 400 for a size or sample that is not valid.
        """
        path, size, sample_b64 = item["path"], item.get("size", 0), item.get("sample", "")
        if not isinstance(size, int) or isinstance(size, bool) or size < 0:
            raise HTTPError(400, f"Invalid 'size' for {path!r}: expected a number of bytes.")
        if not isinstance(sample_b64, str) or len(sample_b64) > 4096:
            raise HTTPError(400, f"Invalid 'sample' for {path!r}: expected the base64 of the file's first 512 bytes.")
        try:
            sample = base64.b64decode(sample_b64, validate=True)
        except (binascii.Error, ValueError):
            raise HTTPError(400, f"Invalid 'sample' for {path!r}: not base64.") from None
        mode = upload_mode(self._rules_for(repo, commit), path, size, sample)
        existing = commit.files.get(path)
        oid = None
        if existing is not None:
            # what the client compares with its own id of the file: sha256 for LFS, git sha1 otherwise
            oid = existing.sha256 if mode == "lfs" else (existing.oid if not existing.lfs else None)
        return {"path": path, "uploadMode": mode, "shouldIgnore": False, "oid": oid}

    # -- routing --

    async def route(self, ctx: Ctx, repo_type: str, repo_id: str, rest: list[str]) -> Response:
        """``/<prefix><repo_id>.git/info/lfs/<rest...>``.

        Args:
            ctx: the request.
            repo_type: ``model``, ``dataset`` or ``space``.
            repo_id: ``namespace/name``.
            rest: the path segments after ``info/lfs``.

        Returns:
            The answer of the batch, verify, upload or multipart route.

        Raises:
            HTTPError: 404 for another path, 405 for another method, or the route's own.
        """
        if rest == ["objects", "batch"]:
            return await call(ctx, {"POST": lambda c: self._batch(c, repo_type, repo_id)}, body=True, write=True)
        if rest == ["objects", "verify"]:
            return await call(ctx, {"POST": lambda c: self._verify(c, repo_type, repo_id)}, body=True, write=True)
        if len(rest) == 4 and rest[:2] == ["objects", "upload"]:
            only(ctx, "PUT")
            return await self._put_basic(ctx, repo_type, repo_id, rest[2], rest[3])
        if len(rest) == 7 and rest[:2] == ["objects", "multipart"]:
            upload_id, oid, size, chunk, part = rest[2:]
            if part == "complete":
                only(ctx, "POST")
                return await self._complete(ctx, repo_type, repo_id, upload_id, oid, size, chunk)
            only(ctx, "PUT")
            return await self._put_part(ctx, repo_type, repo_id, upload_id, oid, size, chunk, part)
        raise HTTPError(404, f"Unknown Git LFS route /{'/'.join(ctx.segs)}: this server speaks the LFS batch API (upload).")

    def no_xet(self, ctx: Ctx) -> Response:
        """The ``/xet-*-token`` routes: 501, saying to set ``HF_HUB_DISABLE_XET=1`` (logged once).

        Args:
            ctx: the request.

        Raises:
            HTTPError: always, 501 ``XetNotSupported``.
        """
        if not self._told_xet:  # hf_xet shows the client only "501 Not Implemented": say it here too, once
            self._told_xet = True
            logger.warning("A client asked for a Xet token (%s). %s", ctx.request.url.path, _NO_XET)
        raise HTTPError(501, _NO_XET, "XetNotSupported")

    # -- signed URLs --

    def _sign(self, *fields: Any) -> str:
        return hmac.new(self._secret, "|".join(map(str, fields)).encode(), hashlib.sha256).hexdigest()

    def _signed_url(self, ctx: Ctx, repo: Repo, path: str, *fields: Any) -> str:
        expires = int(time.time()) + _URL_TTL
        sig = self._sign(repo.repo_type, repo.key[1], path, expires, *fields)
        return f"{repo_url(ctx.base_url, repo.repo_type, repo.repo_id)}.git/info/lfs/objects/{path}?expires={expires}&signature={sig}"

    def _check_signature(self, ctx: Ctx, repo_type: str, repo_id: str, path: str, *fields: Any) -> None:
        expires, sig = ctx.query("expires") or "", ctx.query("signature") or ""
        if not expires.isdigit() or len(expires) > 12:
            raise HTTPError(403, "Invalid upload URL: ask the LFS batch API for a new one.")
        expected = self._sign(repo_type, repo_id.lower(), path, int(expires), *fields)
        if not hmac.compare_digest(expected, sig):
            raise HTTPError(403, "Invalid upload URL (its signature does not match): ask the LFS batch API for a new one.")
        if int(expires) < time.time():
            raise HTTPError(403, "Expired upload URL: ask the LFS batch API for a new one (re-run the upload).")

    # -- batch --

    def _batch(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        data = body_json(ctx)
        if data.get("operation", "upload") != "upload":
            raise HTTPError(400, "Only the 'upload' operation is served by this LFS endpoint: download files through /resolve/.")
        if data.get("hash_algo", "sha256") != "sha256":
            raise HTTPError(400, "Only hash_algo 'sha256' is supported.")
        ref = data.get("ref")
        if isinstance(ref, dict) and isinstance(ref.get("name"), str) and ref["name"]:
            repo.resolve(ref["name"])  # RevisionNotFound if the client uploads for a revision that does not exist
        objects = data.get("objects")
        if not isinstance(objects, list) or len(objects) > _MAX_OBJECTS:
            raise HTTPError(400, f"'objects' must be a list of at most {_MAX_OBJECTS} {{oid, size}}.")
        self._sweep_abandoned()
        transfers = data.get("transfers") or ["basic"]
        multipart = isinstance(transfers, list) and "multipart" in transfers
        free = shutil.disk_usage(self.store.root).free
        out, used = [], "basic"
        for obj in objects:
            oid = obj.get("oid") if isinstance(obj, dict) else None
            size = obj.get("size") if isinstance(obj, dict) else None
            if not isinstance(oid, str) or not _OID_RE.fullmatch(oid):
                raise HTTPError(400, f"Invalid LFS oid {str(oid)[:80]!r}: expected the sha256 of the file, 64 lowercase hex.")
            if not isinstance(size, int) or isinstance(size, bool) or size < 0:
                raise HTTPError(400, f"Invalid size for LFS object {oid}: expected a number of bytes.")
            item: dict[str, Any] = {"oid": oid, "size": size, "authenticated": True}
            have = repo.blob_size(oid)
            if have is not None:
                if have != size:
                    item["error"] = {"code": 422, "message": f"Object {oid} is {have} bytes here, not {size}."}
                out.append(item)  # already held: no actions, the client skips the upload
                continue
            if size > self.max_object:  # the whole request, as the server's other caps: the client raises its HTTP error
                raise HTTPError(
                    413,
                    f"Request too large: LFS object {oid} ({size} bytes) is over {self.max_object / MiB:g} MiB, the limit "
                    f"of one LFS file on this server ({_MAX_LFS_SETTING}).",
                )
            if size > free:
                raise HTTPError(507, f"Not enough disk space on the server for LFS object {oid} ({size} bytes).")
            if multipart and size > self.chunk_size and math.ceil(size / self.chunk_size) <= _MAX_PARTS:
                used = "multipart"
                chunk = self.chunk_size
                upload_id = os.urandom(12).hex()
                base = f"multipart/{upload_id}/{oid}/{size}/{chunk}"
                header = {"chunk_size": str(chunk)}
                for n in range(1, math.ceil(size / chunk) + 1):
                    header[str(n)] = self._signed_url(ctx, repo, f"{base}/{n}")
                item["actions"] = {
                    "upload": {"href": self._signed_url(ctx, repo, f"{base}/complete"), "header": header},
                    "verify": {"href": f"{repo_url(ctx.base_url, repo.repo_type, repo.repo_id)}.git/info/lfs/objects/verify"},
                }
            else:
                item["actions"] = {
                    "upload": {"href": self._signed_url(ctx, repo, f"upload/{oid}/{size}")},
                    "verify": {"href": f"{repo_url(ctx.base_url, repo.repo_type, repo.repo_id)}.git/info/lfs/objects/verify"},
                }
            out.append(item)
        return Response(
            json.dumps({"transfer": used, "objects": out, "hash_algo": "sha256"}), media_type=_LFS_JSON, status_code=200
        )

    def _sweep_abandoned(self) -> None:
        """Remove multipart uploads whose URLs have expired (a client that never completed them); at most
        every 10 minutes, from a batch request."""
        now = time.time()
        if now - self._swept < 600:
            return
        self._swept = now
        for path in (self.store.root / "tmp").glob("lfs-multipart-*"):
            try:
                if now - path.stat().st_mtime > _URL_TTL:
                    shutil.rmtree(path, ignore_errors=True)
            except OSError:
                continue

    def _verify(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        data = body_json(ctx)
        oid, size = data.get("oid"), data.get("size")
        if not isinstance(oid, str) or not _OID_RE.fullmatch(oid):
            raise HTTPError(400, "Invalid 'oid': expected the sha256 of the file, 64 lowercase hex.")
        have = repo.blob_size(oid)
        if have is None:
            raise HTTPError(404, f"LFS object {oid} was not uploaded to {repo.repo_id}: upload it again.")
        if size is not None and size != have:
            raise HTTPError(422, f"LFS object {oid} is {have} bytes on the server, not {size}: upload it again.")
        return json_response({})

    # -- uploads --

    def _upload_target(self, ctx: Ctx, repo_type: str, repo_id: str, oid: str, size: str) -> tuple[Repo, int]:
        if not _OID_RE.fullmatch(oid) or not size.isdigit() or len(size) > 18:
            raise HTTPError(400, "Malformed LFS upload URL: ask the LFS batch API for a new one.")
        repo = self.store.open(repo_type, repo_id)  # it may have been deleted since the batch call
        return repo, int(size)

    def _check_length(self, ctx: Ctx, expected: int, what: str) -> None:
        declared = ctx.request.headers.get("content-length", "").strip()
        if declared.isdigit() and (len(declared) > 18 or int(declared) != expected):
            raise HTTPError(400, f"{what}: Content-Length {declared[:20]} announced, {expected} bytes expected.")

    async def _receive(self, ctx: Ctx, fd: int, offset: int, expected: int, what: str) -> str:
        """Stream the request body into ``fd`` at ``offset`` (exactly ``expected`` bytes, else 400);
        return its sha256. Written and hashed in a worker thread, ``_FLUSH`` bytes at a time."""
        hasher = hashlib.sha256()
        received = 0
        buf = bytearray()

        def flush(data: bytearray, at: int) -> None:
            hasher.update(data)
            view = memoryview(data)
            while view:
                written = os.pwrite(fd, view, at)
                view, at = view[written:], at + written

        pos = offset
        async for chunk in ctx.request.stream():
            received += len(chunk)
            if received > expected:
                raise HTTPError(400, f"{what}: more than the {expected} bytes announced.")
            buf += chunk
            if len(buf) >= _FLUSH:
                data, buf = buf, bytearray()  # handed over, not copied
                await run_in_threadpool(flush, data, pos)
                pos += len(data)
                del data
        if buf:
            await run_in_threadpool(flush, buf, pos)
        if received != expected:
            raise HTTPError(400, f"{what}: {received} bytes received, {expected} announced (interrupted?). Upload it again.")
        return hasher.hexdigest()

    async def _put_basic(self, ctx: Ctx, repo_type: str, repo_id: str, oid: str, size_s: str) -> Response:
        self._check_signature(ctx, repo_type, repo_id, f"upload/{oid}/{size_s}")
        repo, size = await run_in_threadpool(self._upload_target, ctx, repo_type, repo_id, oid, size_s)
        what = f"LFS upload of {oid} to {repo.repo_id}"
        self._check_length(ctx, size, what)
        scratch = self.store.scratch_path("lfs-")
        fd = os.open(scratch, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        adopted = False
        try:
            try:
                digest = await self._receive(ctx, fd, 0, size, what)
                if self.store.fsync:
                    await run_in_threadpool(os.fsync, fd)
            finally:
                os.close(fd)
            if digest != oid:
                raise HTTPError(
                    400,
                    f"{what}: the bytes received hash to sha256 {digest}, not {oid}. Nothing was stored; upload the file again.",
                    "LfsChecksumMismatch",
                )
            await run_in_threadpool(repo.adopt_blob, scratch, oid)
            adopted = True
        finally:
            if not adopted:
                scratch.unlink(missing_ok=True)
        logger.info("lfs: stored %s (%d bytes) in %s %s via basic", oid, size, repo.repo_type, repo.repo_id)
        return Response(b"", status_code=200)

    def _multipart(self, ctx: Ctx, repo_type: str, repo_id: str, upload_id: str, oid: str, size_s: str, chunk_s: str):
        if not re.fullmatch(r"[0-9a-f]{24}", upload_id) or not chunk_s.isdigit() or len(chunk_s) > 18:
            raise HTTPError(400, "Malformed LFS upload URL: ask the LFS batch API for a new one.")
        repo, size = self._upload_target(ctx, repo_type, repo_id, oid, size_s)
        chunk = int(chunk_s)
        if chunk < 1:
            raise HTTPError(400, "Malformed LFS upload URL: ask the LFS batch API for a new one.")
        root = self.store.root / "tmp" / f"lfs-multipart-{upload_id}"
        return repo, size, chunk, root

    async def _put_part(self, ctx, repo_type, repo_id, upload_id, oid, size_s, chunk_s, part_s) -> Response:
        base = f"multipart/{upload_id}/{oid}/{size_s}/{chunk_s}"
        self._check_signature(ctx, repo_type, repo_id, f"{base}/{part_s}")
        repo, size, chunk, root = await run_in_threadpool(
            self._multipart, ctx, repo_type, repo_id, upload_id, oid, size_s, chunk_s
        )
        parts = math.ceil(size / chunk)
        if not part_s.isdigit() or not 1 <= int(part_s) <= parts:
            raise HTTPError(400, f"Invalid part number {part_s[:20]!r}: this upload has parts 1 to {parts}.")
        n = int(part_s)
        offset = (n - 1) * chunk
        expected = min(chunk, size - offset)
        what = f"LFS upload of {oid} to {repo.repo_id}, part {n}/{parts}"
        self._check_length(ctx, expected, what)
        root.mkdir(exist_ok=True)
        fd = os.open(root / "data", os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            digest = await self._receive(ctx, fd, offset, expected, what)
            if self.store.fsync:
                await run_in_threadpool(os.fsync, fd)
        finally:
            os.close(fd)
        etag = f'"{digest}"'
        (root / f"part-{n}").write_text(etag)  # this part arrived whole: its ETag, for the completion
        return Response(b"", status_code=200, headers={"ETag": etag})

    async def _complete(self, ctx, repo_type, repo_id, upload_id, oid, size_s, chunk_s) -> Response:
        base = f"multipart/{upload_id}/{oid}/{size_s}/{chunk_s}"
        self._check_signature(ctx, repo_type, repo_id, f"{base}/complete")
        repo, size, chunk, root = await run_in_threadpool(
            self._multipart, ctx, repo_type, repo_id, upload_id, oid, size_s, chunk_s
        )
        ctx.body = await read_body(ctx)
        data = body_json(ctx)
        parts = math.ceil(size / chunk)
        sent = data.get("parts")
        if data.get("oid") != oid or not isinstance(sent, list) or len(sent) != parts:
            raise HTTPError(400, f"Malformed completion of the LFS upload of {oid}: expected its oid and all {parts} parts.")

        def finish() -> None:
            for i, part in enumerate(sent, start=1):
                marker = root / f"part-{i}"
                if not isinstance(part, dict) or part.get("partNumber") != i:
                    raise HTTPError(400, f"Malformed completion of the LFS upload of {oid}: parts must be listed 1 to {parts}.")
                if not marker.is_file() or marker.read_text() != str(part.get("etag")):
                    raise HTTPError(
                        400, f"LFS upload of {oid} to {repo.repo_id}: part {i} was not received whole. Upload the file again."
                    )
            data_path = root / "data"
            hasher = hashlib.sha256()
            with open(data_path, "rb") as f:
                total = 0
                while piece := f.read(_HASH_PIECE):
                    hasher.update(piece)
                    total += len(piece)
            if total != size or hasher.hexdigest() != oid:
                raise HTTPError(
                    400,
                    f"LFS upload of {oid} to {repo.repo_id}: the parts hash to sha256 {hasher.hexdigest()} ({total} bytes), "
                    f"not {oid} ({size} bytes). Nothing was stored; upload the file again.",
                    "LfsChecksumMismatch",
                )
            repo.adopt_blob(data_path, oid)

        try:
            await run_in_threadpool(finish)
        finally:
            shutil.rmtree(root, ignore_errors=True)
        logger.info("lfs: stored %s (%d bytes) in %s %s via multipart (%d parts)", oid, size, repo.repo_type, repo.repo_id, parts)
        return json_response({})
