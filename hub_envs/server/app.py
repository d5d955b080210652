"""The HTTP routes of the loopback Hub server: the subset of the Hugging Face Hub API that
``huggingface_hub`` (0.34/0.35, requests-based, and 1.x, httpx-based) uses to create repos, commit,
tag, list and download.

Requests are routed on the *raw* (still percent-encoded) path, split on ``/`` before decoding,
because the client percent-encodes revisions and tree paths as single segments
(``refs%2Fpr%2F1``, ``a%2Fb``) and a decoded ``/`` must not shift the route.

Protocol notes (matching huggingface.co, as ``huggingface_hub`` reads it):

* Errors carry ``X-Error-Code`` (``RepoNotFound``, ``RevisionNotFound``, ``EntryNotFound``) and
  ``X-Error-Message`` headers and a ``{"error": message}`` body, so the client raises its typed
  errors. A missing or private repo answers 401 to anonymous callers and 404 to authenticated ones.
* Repo privacy comes as ``"private": bool`` (0.x clients) or ``"visibility"`` (1.x clients) in
  ``/api/repos/create`` and ``PUT .../settings``; both are understood, and repo info reports ``private``.
* ``/preupload`` answers ``"lfs"`` or ``"regular"`` by the Hub's rules (the repo's ``.gitattributes``
  LFS patterns, files over 10 MiB, binary samples), and the ``oid`` of files already present, which
  lets the client skip no-op commits as it does against the Hub. Regular files come inline, base64,
  in the NDJSON commit; LFS files through the Git LFS batch API (basic and multipart transfers,
  streamed to disk, sha256-checked) and an ``lfsFile`` commit line: see :mod:`hub_envs.server.lfs`.
  Xet is not offered (``xetEnabled: false``; ``/xet-*-token`` answers 501 naming ``HF_HUB_DISABLE_XET=1``).
* A stale ``parentCommit`` is refused with 412 and the Hub's message.
* Pull requests: ``commit/<branch>?create_pr=1`` opens ``refs/pr/N`` (from the branch head, or from
  ``parentCommit``) and answers its ``pullRequestUrl`` (``.../discussions/N``); a commit to
  ``refs/pr/N`` adds to an open one; ``/discussions`` lists them (paged by ``p``, 50 a page),
  ``/discussions/N`` details them (events, ``changes.base``, ``mergeCommitId``), ``/discussions/N/merge``
  merges (a merge commit; 409 with ``filesWithConflicts`` when the branch changed the same files) and
  ``/discussions/N/status`` closes or reopens. Any account may open one on a repo it can read; only the
  owner merges, and the owner or its author pushes to it and closes it. Every read takes ``revision=refs/pr/N``.
  Plain discussions (comments without changes) are not kept.
* ``/resolve`` answers HEAD and GET with ``X-Repo-Commit``, ``ETag`` (the git blob sha1; for an
  LFS file its sha256, also in ``X-Linked-Etag``, with ``X-Linked-Size``), ``Content-Length`` and
  ``Accept-Ranges``, and serves single ``Range`` requests with 206.
* Lists (tree, commits) are paged with a ``Link: <...>; rel="next"`` header.
* Paths that could escape a repo (``..``, absolute, ``\\``, NUL, percent-encoded variants) get 400,
  as do control characters (C0, DEL, C1) and names over 255 bytes.

Limits (a hostile client must not be able to take the server down):

* Writes are authenticated before any request body is read.
* Request bodies are capped (``max_body_mb``, env ``HUB_ENVS_SERVER_MAX_BODY_MB``, default 2048), and
  so is each NDJSON line of a commit (``max_line_mb``, env ``HUB_ENVS_SERVER_MAX_LINE_MB``, default
  16: one line carries one inline file, base64, and files over 10 MiB go through LFS) and every JSON body
  (32 MiB); over a cap: 413. Commit
  bodies are read incrementally; their lines are parsed, decoded and stored in a worker thread, a
  large file's base64 in 1 MiB pieces, so other requests keep being served during a big upload.
* README metadata (``cardData``) is parsed with limits: at most 64 KiB of front matter, no YAML
  aliases, nesting at most 64 deep. A card over a limit is left out of that repo's info (and
  logged); it never fails the listing or another repo's routes.
* A 500 answers a generic message; the details go to the server's log only.
* Web pages run in threads of their own (8), never the API's; a card's Markdown is rendered in a worker
  process within a time budget (see :class:`~hub_envs.server.pages.CardRenderer`).
* :func:`hub_envs.server.run` gives uvicorn a deadline for request heads (20 s), a keep-alive timeout (5 s)
  and a cap on connections (1000).
* In env repos (those with a ``hub_env.json`` manifest at the root), commits may not add compiled
  Python bytecode (``__pycache__/``, ``.pyc``, ``.pyo``): Python would run it instead of the sources.
  (huggingface.co stores it; ``HUB_ENVS_SERVER_ALLOW_BYTECODE=1`` does too, to test clients.)

Example:
    >>> import tempfile
    >>> from starlette.testclient import TestClient
    >>> from hub_envs.server import create_app
    >>> client = TestClient(create_app(tempfile.mkdtemp()))
    >>> client.post("/api/repos/create", json={"name": "pendulum", "organization": "alice"}).json()["url"]
    'http://testserver/alice/pendulum'
    >>> r = client.head("/alice/pendulum/resolve/main/.gitattributes")
    >>> r.status_code, len(r.headers["X-Repo-Commit"]), r.headers["Accept-Ranges"]
    (200, 40, 'bytes')
    >>> r = client.get("/alice/pendulum/resolve/main/nope.txt")
    >>> r.status_code, r.headers["X-Error-Code"]
    (404, 'EntryNotFound')
    >>> client.get("/alice/pendulum/resolve/main/%2e%2e/%2e%2e/FORMAT").status_code
    400
"""

from __future__ import annotations

import base64
import binascii
import datetime
import hashlib
import hmac
import html
import json
import logging
import math
import mimetypes
import os
import re
import threading
from collections import OrderedDict
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qs, quote, unquote, urlencode

import anyio
import anyio.to_thread
import yaml
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route

from hub_envs.errors import ConfigError
from hub_envs.server.faults import install_faults
from hub_envs.server.lfs import LfsRoutes
from hub_envs.server.lfs import logger as lfs_logger
from hub_envs.server.pages import Pages, ResolveSandbox
from hub_envs.server.storage import (
    DEFAULT_BRANCH,
    REPO_TYPES,
    AddFile,
    Change,
    Commit,
    DeleteFile,
    DeleteFolder,
    EntryNotFoundError,
    HubStore,
    InvalidNameError,
    InvalidOperationError,
    InvalidPathError,
    MergeConflictError,
    ParentMismatchError,
    PullRequest,
    PullRequestNotFoundError,
    RefExistsError,
    Repo,
    RepoExistsError,
    RepoNotFoundError,
    RevisionNotFoundError,
    StoreError,
    folders_of,
    format_date,
    now,
    validate_path,
)

logger = logging.getLogger("hub_envs.server")

DEFAULT_USER = "local"
TREE_PAGE_SIZE = 1000
COMMITS_PAGE_SIZE = 50
DISCUSSIONS_PAGE_SIZE = 50
_CHUNK = 1024 * 1024
_PLURAL = {"models": "model", "datasets": "dataset", "spaces": "space"}
_URL_PREFIX = {"model": "", "dataset": "datasets/", "space": "spaces/"}
_SPACE_SDKS = ("gradio", "streamlit", "docker", "static")
_INVALID_CREDENTIALS = "Invalid credentials in Authorization header"
_INTERNAL_ERROR = "Internal server error: the request failed on the server (the details are in the server's log)."

MiB = 1024 * 1024
#: Default caps (MiB) of a request body and of one NDJSON line of a commit. A line carries one file inline,
#: base64-encoded (4/3 of its size), and is held in memory while it is stored. Only "regular" files come
#: inline: /preupload sends every file over 10 MiB (lfs.LFS_SIZE_THRESHOLD), and every binary one, through Git
#: LFS, so huggingface_hub's largest line is a 10 MiB text file: 13.3 MiB of base64 plus its path. A commit
#: body carries all of its inline files, read line by line (never whole).
DEFAULT_MAX_BODY_MB = 2048.0
DEFAULT_MAX_LINE_MB = 16.0
_MAX_JSON_BODY = 32 * MiB  # the JSON bodies of the other routes (preupload, paths-info, validate-yaml...)
_BODY_SETTING = "--max_body_mb / HUB_ENVS_SERVER_MAX_BODY_MB"
_LINE_SETTING = "--max_line_mb / HUB_ENVS_SERVER_MAX_LINE_MB"
_LINE_LIMIT = (
    f"the limit of one commit line, i.e. one inline file in base64 ({_LINE_SETTING}); files over 10 MiB go through "
    "Git LFS, as huggingface_hub sends them when /preupload says so"
)
_B64_PIECE = MiB  # base64 decoded this much at a time: the GIL is released between pieces
_BIG_LINE = MiB  # lines over this size get the fast path of _parse_line
# The README front matter (cardData): parsed with these limits, or left out.
_CARD_MAX_BYTES = 64 * 1024
_CARD_MAX_DEPTH = 64
_CARD_CACHE_SIZE = 1024
_PAGE_THREADS = 8  # web pages render in at most this many threads: a slow page never takes the API's threads
_ENV_MANIFEST = "hub_env.json"  # hub_envs.repo_format.MANIFEST_FILE: what makes a repo an env repo


class HTTPError(Exception):
    """An error answered as-is: status, message, and the Hub's ``X-Error-Code`` when it has one."""

    def __init__(
        self, status: int, message: str, code: str | None = None, headers: dict | None = None, extra: dict | None = None
    ):
        super().__init__(message)
        self.status = status
        self.message = message
        self.code = code
        self.headers = headers or {}
        self.extra = extra or {}  # more fields of the JSON body


@dataclass
class Ctx:
    """One request, parsed: decoded path segments, query, body, and who is calling."""

    request: Request
    method: str
    segs: list[str]
    user: str | None  # None: anonymous (only when the server has a token and none was sent)
    body: bytes = b""

    @property
    def authenticated(self) -> bool:
        return self.user is not None

    @property
    def base_url(self) -> str:
        return str(self.request.base_url).rstrip("/")

    def query(self, name: str, default: str | None = None) -> str | None:
        return self.request.query_params.get(name, default)

    def flag(self, name: str) -> bool:
        return (self.query(name) or "").lower() in ("1", "true", "yes")


def _header_safe(message: str) -> str:
    return re.sub(r"[^\x20-\x7e]", "?", message)[:1000]


def _json(data: Any, status: int = 200, headers: dict | None = None) -> Response:
    return Response(json.dumps(data), status_code=status, headers=headers, media_type="application/json")


def _error_response(err: HTTPError) -> Response:
    headers = {"X-Error-Message": _header_safe(err.message), **err.headers}
    if err.code:
        headers["X-Error-Code"] = err.code
    return _json({"error": err.message, **err.extra}, status=err.status, headers=headers)


class HubApp:
    """The routes, bound to one :class:`~hub_envs.server.storage.HubStore`. See :func:`create_app`."""

    def __init__(
        self,
        root: str | os.PathLike,
        token: str | None = None,
        *,
        page_size: int | None = None,
        user: str | None = None,
        fsync: bool | None = None,
        max_body_mb: float | None = None,
        max_line_mb: float | None = None,
        allow_bytecode: bool | None = None,
        max_lfs_mb: float | None = None,
        users: dict[str, str] | None = None,
    ):
        if fsync is None:
            fsync = os.environ.get("HUB_ENVS_SERVER_FSYNC", "1").lower() not in ("0", "false", "no")
        self.token = token or None
        self.user = user or os.environ.get("HUB_ENVS_SERVER_USER") or DEFAULT_USER
        # more accounts (token -> name): each owns its own namespace only; see _can_manage
        self.users = dict(users) if users is not None else _users_from_env(os.environ.get("HUB_ENVS_SERVER_USERS", ""))
        if self.users and self.token is None:  # an anonymous caller would act as the owner, who manages every repo
            names = ", ".join(sorted(set(self.users.values())))
            raise ConfigError(
                f"Accounts are configured (HUB_ENVS_SERVER_USERS: {names}) but the server has no token: every request "
                f"without a token would act as the owner account {self.user!r}, which may create repos in any namespace "
                f"and delete any repo. Start it with --token=<the owner's token> (clients of {self.user!r} set HF_TOKEN "
                "to it), or without HUB_ENVS_SERVER_USERS for a single-account server open to anyone."
            )
        self.store = HubStore(root, fsync=fsync)
        if page_size is None and os.environ.get("HUB_ENVS_SERVER_PAGE_SIZE"):
            page_size = int(os.environ["HUB_ENVS_SERVER_PAGE_SIZE"])
        if page_size is not None and page_size < 1:
            raise ValueError(f"page_size must be >= 1, got {page_size}.")
        self.tree_page_size = page_size or TREE_PAGE_SIZE
        self.commits_page_size = page_size or COMMITS_PAGE_SIZE
        self.max_body = _limit_bytes(max_body_mb, "HUB_ENVS_SERVER_MAX_BODY_MB", DEFAULT_MAX_BODY_MB, "max_body_mb")
        self.max_line = _limit_bytes(max_line_mb, "HUB_ENVS_SERVER_MAX_LINE_MB", DEFAULT_MAX_LINE_MB, "max_line_mb")
        if allow_bytecode is None:
            allow_bytecode = os.environ.get("HUB_ENVS_SERVER_ALLOW_BYTECODE", "").lower() in ("1", "true", "yes")
        self.allow_bytecode = allow_bytecode  # as huggingface.co does: to test clients against it
        self._cards: OrderedDict[str, dict | None] = OrderedDict()  # README sha256 -> cardData
        self._cards_guard = threading.Lock()
        self.pages = Pages(self)  # the web pages
        self._page_threads: anyio.CapacityLimiter | None = None  # pages wait for these, never for the API's threads
        self.lfs = LfsRoutes(self, max_lfs_mb=max_lfs_mb)  # Git LFS: preupload rules, batch API, uploads

    # -- entry point ---------------------------------------------------------------------------

    async def endpoint(self, request: Request) -> Response:
        method = request.method
        raw = request.scope.get("raw_path") or request.url.path.encode()
        segs = [unquote(s) for s in raw.decode("latin-1").split("/")[1:]]
        if segs and segs[-1] == "" and len(segs) > 1:
            segs = segs[:-1]
        try:
            ctx = Ctx(request, method, segs, self._caller(request))
            return await self._route(ctx)
        except HTTPError as err:
            return _error_response(err)
        except StoreError as err:
            return _error_response(self._store_error(err, request))
        except ClientDisconnect:  # the client went away mid-body: nobody reads this answer
            return _error_response(HTTPError(400, "Client disconnected before sending the whole request body."))
        except Exception:  # a bug: log it, answer 500 without its details (paths, internals)
            logger.exception("Internal error on %s %s", method, request.url.path)
            return _error_response(HTTPError(500, _INTERNAL_ERROR))

    def _caller(self, request: Request) -> str | None:
        header = (request.headers.get("authorization") or "").strip()
        for token, name in self.users.items():  # the other accounts, with or without a server token
            if header and hmac.compare_digest(header.encode(), f"Bearer {token}".encode()):
                return name
        if self.token is None:
            return self.user  # open server: everyone else is the server's user
        if not header:
            return None
        if not hmac.compare_digest(header.encode(), f"Bearer {self.token}".encode()):
            raise HTTPError(401, _INVALID_CREDENTIALS)
        return self.user

    def _store_error(self, err: StoreError, request: Request) -> HTTPError:
        message = str(err)
        if isinstance(err, RepoNotFoundError):
            anonymous = self.token is not None and not request.headers.get("authorization")
            return HTTPError(401 if anonymous else 404, "Repository not found", "RepoNotFound")
        if isinstance(err, RevisionNotFoundError):
            return HTTPError(404, message, "RevisionNotFound")
        if isinstance(err, EntryNotFoundError):
            return HTTPError(404, message, "EntryNotFound")
        if isinstance(err, (RepoExistsError, RefExistsError)):
            return HTTPError(409, message)
        if isinstance(err, ParentMismatchError):
            return HTTPError(412, message)
        if isinstance(err, PullRequestNotFoundError):
            return HTTPError(404, message)
        if isinstance(err, MergeConflictError):
            return HTTPError(409, message, extra={"filesWithConflicts": err.files})
        if isinstance(err, (InvalidPathError, InvalidNameError, InvalidOperationError)):
            return HTTPError(400, message)
        logger.error("Store error on %s %s: %s", request.method, request.url.path, message)
        return HTTPError(500, _INTERNAL_ERROR)

    # -- routing -------------------------------------------------------------------------------

    async def _route(self, ctx: Ctx) -> Response:
        segs = ctx.segs
        page = self.pages.match(ctx) if ctx.method in ("GET", "HEAD") else None
        if page is not None:  # the web pages (pages.py): "/" for browsers, /{user}/{repo}[/tree|blob|commits/...]
            if self._page_threads is None:  # made in the event loop (anyio 3 needs one)
                self._page_threads = anyio.CapacityLimiter(_PAGE_THREADS)
            return await self._call(ctx, {"GET": lambda c: self.pages.handle(c, page)}, threads=self._page_threads)
        if segs and segs[0] == "api":
            rest = segs[1:]
            if rest == ["whoami-v2"]:
                return await self._call(ctx, {"GET": self.whoami})
            if rest == ["validate-yaml"]:
                return await self._call(ctx, {"POST": self.validate_yaml}, body=True, write=True)
            if rest == ["repos", "create"]:
                return await self._call(ctx, {"POST": self.create_repo}, body=True, write=True)
            if rest == ["repos", "delete"]:
                return await self._call(ctx, {"DELETE": self.delete_repo}, body=True, write=True)
            if len(rest) == 1 and rest[0] in _PLURAL:
                return await self._call(ctx, {"GET": lambda c: self.list_repos(c, _PLURAL[rest[0]])})
            if len(rest) >= 3 and rest[0] in _PLURAL:
                return await self._repo_api(ctx, _PLURAL[rest[0]], f"{rest[1]}/{rest[2]}", rest[3:])
            raise HTTPError(404, f"Unknown API route /{'/'.join(segs)}.")
        # /[datasets|spaces|models/]<ns>/<name>/resolve/<rev>/<path...>
        repo_type, rest = "model", segs
        if rest and rest[0] in _PLURAL:
            repo_type, rest = _PLURAL[rest[0]], rest[1:]
        if len(rest) >= 4 and rest[1].endswith(".git") and rest[2:4] == ["info", "lfs"]:  # Git LFS
            return await self.lfs.route(ctx, repo_type, f"{rest[0]}/{rest[1][: -len('.git')]}", rest[4:])
        if len(rest) >= 4 and rest[2] == "resolve":
            repo_id, revision, path = f"{rest[0]}/{rest[1]}", rest[3], "/".join(rest[4:])
            handlers = {m: (lambda c: self.resolve(c, repo_type, repo_id, revision, path)) for m in ("GET", "HEAD")}
            return await self._call(ctx, handlers)
        raise HTTPError(404, f"Not found: /{'/'.join(segs)}.")

    async def _repo_api(self, ctx: Ctx, repo_type: str, repo_id: str, rest: list[str]) -> Response:
        action = rest[0] if rest else None
        arg = rest[1] if len(rest) > 1 else None
        if action is None:
            return await self._call(ctx, {"GET": lambda c: self.repo_info(c, repo_type, repo_id, None)})
        if action == "revision" and arg is not None:
            revision = "/".join(rest[1:])
            return await self._call(ctx, {"GET": lambda c: self.repo_info(c, repo_type, repo_id, revision)})
        if action == "tree" and arg is not None:
            path = "/".join(rest[2:])
            return await self._call(ctx, {"GET": lambda c: self.tree(c, repo_type, repo_id, arg, path)})
        if action == "paths-info" and arg is not None:
            return await self._call(ctx, {"POST": lambda c: self.paths_info(c, repo_type, repo_id, arg)}, body=True)
        if action == "refs" and arg is None:
            return await self._call(ctx, {"GET": lambda c: self.list_refs(c, repo_type, repo_id)})
        if action == "commits" and arg is not None:
            revision = "/".join(rest[1:])
            return await self._call(ctx, {"GET": lambda c: self.list_commits(c, repo_type, repo_id, revision)})
        if action == "preupload" and arg is not None:
            return await self._call(ctx, {"POST": lambda c: self.preupload(c, repo_type, repo_id, arg)}, body=True, write=True)
        if action == "commit" and arg is not None:
            if ctx.method != "POST":
                raise HTTPError(405, "Method not allowed: use POST to commit.")
            # An error answered before the whole body is read is fine: the server (uvicorn) reads
            # and discards the rest, so the client still gets the answer.
            return await self.commit(ctx, repo_type, repo_id, "/".join(rest[1:]))
        if action in ("branch", "tag") and arg is not None:  # create (POST) or delete (DELETE) a ref
            ref = "/".join(rest[1:])
            create = self.create_branch if action == "branch" else self.create_tag
            return await self._call(
                ctx,
                {
                    "POST": lambda c: create(c, repo_type, repo_id, ref),
                    "DELETE": lambda c: self.delete_ref(c, repo_type, repo_id, action, ref),
                },
                body=True,
                write=True,
            )
        if action == "discussions":
            return await self._discussions_api(ctx, repo_type, repo_id, rest[1:])
        if action in ("xet-write-token", "xet-read-token"):  # Xet is not offered: say what to do instead
            return await self._call(ctx, {m: self.lfs.no_xet for m in ("GET", "POST")})
        if action == "settings" and arg is None:
            return await self._call(ctx, {"PUT": lambda c: self.settings(c, repo_type, repo_id)}, body=True, write=True)
        raise HTTPError(404, f"Unknown API route /{'/'.join(ctx.segs)}.")

    async def _discussions_api(self, ctx: Ctx, repo_type: str, repo_id: str, rest: list[str]) -> Response:
        """``/discussions`` (list), ``/discussions/<num>`` (details), ``/discussions/<num>/merge`` and ``/status``."""
        if not rest:
            return await self._call(ctx, {"GET": lambda c: self.list_discussions(c, repo_type, repo_id)})
        if not rest[0].isdigit() or len(rest[0]) > 9 or int(rest[0]) < 1:
            raise HTTPError(400, f"Invalid discussion number {rest[0][:20]!r}: expected a positive integer.")
        num = int(rest[0])
        if len(rest) == 1:
            return await self._call(ctx, {"GET": lambda c: self.discussion_details(c, repo_type, repo_id, num)})
        if len(rest) == 2 and rest[1] == "merge":
            return await self._call(ctx, {"POST": lambda c: self.merge_pr(c, repo_type, repo_id, num)}, body=True, write=True)
        if len(rest) == 2 and rest[1] == "status":
            return await self._call(
                ctx, {"POST": lambda c: self.discussion_status(c, repo_type, repo_id, num)}, body=True, write=True
            )
        raise HTTPError(404, f"Unknown API route /{'/'.join(ctx.segs)}: this server has pull requests, not comments.")

    async def _call(
        self,
        ctx: Ctx,
        handlers: dict[str, Callable],
        body: bool = False,
        write: bool = False,
        threads: anyio.CapacityLimiter | None = None,
    ) -> Response:
        """Run the handler of ``ctx.method`` in a worker thread; ``write``: authenticate first;
        ``body``: read the (JSON) request body into ``ctx.body`` first, capped; ``threads``: the threads to
        run it in (default: the API's)."""
        handler = handlers.get(ctx.method)
        if handler is None and ctx.method == "HEAD":
            handler = handlers.get("GET")  # HEAD is GET without the body (uvicorn drops it)
        if handler is None:
            allowed = ", ".join(sorted(handlers))
            raise HTTPError(405, f"Method {ctx.method} not allowed here (allowed: {allowed}).", headers={"Allow": allowed})
        if write:
            self._require_write(ctx)  # before reading a single byte of the body
        if body:
            ctx.body = await self._read_body(ctx)
        if threads is not None:
            return await anyio.to_thread.run_sync(handler, ctx, limiter=threads)
        return await run_in_threadpool(handler, ctx)

    def _json_body_limit(self) -> tuple[int, str]:
        if self.max_body < _MAX_JSON_BODY:
            return self.max_body, f"the request body limit of this server ({_BODY_SETTING})"
        return _MAX_JSON_BODY, "the limit of JSON request bodies on this server"

    def _check_declared_length(self, ctx: Ctx, limit: int, what: str) -> None:
        """413 at once if ``Content-Length`` announces more than ``limit``: nothing is read."""
        declared = ctx.request.headers.get("content-length", "").strip()
        if declared.isdigit() and (len(declared) > 18 or int(declared) > limit):
            raise _too_large(limit, what)

    async def _read_body(self, ctx: Ctx) -> bytes:
        limit, what = self._json_body_limit()
        self._check_declared_length(ctx, limit, what)
        body = bytearray()
        async for chunk in ctx.request.stream():
            body += chunk
            if len(body) > limit:
                raise _too_large(limit, what)
        return bytes(body)

    # -- helpers -------------------------------------------------------------------------------

    def _require_write(self, ctx: Ctx) -> str:
        if ctx.user is None:
            raise HTTPError(
                401,
                "Authentication required: this hub-envs server was started with --token, and write requests "
                "must send it (`Authorization: Bearer <token>`). Set HF_TOKEN to that token, or pass token=...",
            )
        return ctx.user

    def _can_manage(self, user: str | None, repo: Repo) -> bool:
        """Whether ``user`` may write to ``repo`` directly, merge or close its pull requests: the server's own
        account manages every repo (a single-user server as before); another account (``users``) its namespace."""
        if user is None:
            return False
        return user == self.user or user.lower() == repo.repo_id.split("/")[0].lower()

    def _require_manage(self, ctx: Ctx, repo: Repo, what: str) -> None:
        if not self._can_manage(ctx.user, repo):
            raise HTTPError(
                403,
                f"{ctx.user} cannot {what} {repo.repo_id}: only its owner can. "
                "Open a pull request instead (create_commit(..., create_pr=True)).",
            )

    def _require_push(self, ctx: Ctx, repo: Repo, branch: str) -> None:
        """403 unless ``ctx.user`` may commit to ``branch``: a branch needs the repo's owner (:meth:`_can_manage`);
        a pull request's ``refs/pr/N`` its owner or the account that opened it (everyone else opens a pull request
        of their own). Checked before any of the body is read."""
        if self._can_manage(ctx.user, repo):
            return
        num = branch[len("refs/pr/") :] if branch.startswith("refs/pr/") else ""
        if not (num.isdigit() and len(num) <= 9):
            self._require_manage(ctx, repo, "commit to")
        pr = repo.pull_request(int(num))  # 404 if there is none
        if pr.author != ctx.user:
            raise HTTPError(
                403,
                f"{ctx.user} cannot push to {branch} of {repo.repo_id}: only the pull request's author ({pr.author}) "
                "or the repo's owner can. Open a pull request of your own instead (create_commit(..., create_pr=True)).",
            )

    def _open(self, ctx: Ctx, repo_type: str, repo_id: str, write: bool = False) -> Repo:
        if write:
            self._require_write(ctx)
        repo = self.store.open(repo_type, repo_id)
        if repo.meta.private and not ctx.authenticated:
            raise RepoNotFoundError(f"Repository {repo_id!r} not found.")
        return repo

    def _body_json(self, ctx: Ctx) -> dict:
        raw = ctx.body
        if not raw.strip():
            return {}
        try:
            data = json.loads(raw)
        except ValueError as err:
            raise HTTPError(400, f"Request body is not valid JSON: {err}.") from None
        except RecursionError:
            raise HTTPError(400, "Request body is not valid JSON: nested too deeply.") from None
        if not isinstance(data, dict):
            raise HTTPError(400, "Request body must be a JSON object.")
        return data

    def _repo_url(self, ctx: Ctx, repo: Repo | str, repo_type: str | None = None) -> str:
        if isinstance(repo, Repo):
            repo_type, repo_id = repo.repo_type, repo.repo_id
        else:
            repo_id = repo
        return f"{ctx.base_url}/{_URL_PREFIX[repo_type or 'model']}{repo_id}"

    def _page(self, ctx: Ctx, items: list, size: int, param: str) -> tuple[list, dict]:
        try:
            start = int(ctx.query(param) or 0)
            limit = int(ctx.query("limit") or size)
        except ValueError:
            raise HTTPError(400, f"Invalid '{param}' or 'limit' query parameter.") from None
        start, limit = max(start, 0), max(1, min(limit, size))
        if param == "p":
            start *= limit
        page = items[start : start + limit]
        headers = {}
        if start + limit < len(items):
            nxt = start + limit if param != "p" else (start + limit) // limit
            # from the raw path: a decoded one would turn "feature%2Fx" into two segments
            raw_path = (ctx.request.scope.get("raw_path") or ctx.request.url.path.encode()).decode("latin-1")
            query = [(k, v) for k, v in ctx.request.query_params.multi_items() if k != param] + [(param, str(nxt))]
            headers["Link"] = f'<{ctx.base_url}{raw_path}?{urlencode(query)}>; rel="next"'
        return page, headers

    def _card_data(self, repo: Repo, commit: Commit) -> dict | None:
        """The README's metadata as JSON-ready data, or None: no README, no metadata, or metadata
        over the limits or invalid (logged). Cached by README content."""
        entry = commit.files.get("README.md")
        if entry is None:
            return None
        with self._cards_guard:
            if entry.sha256 in self._cards:
                self._cards.move_to_end(entry.sha256)
                return self._cards[entry.sha256]
        card = None
        try:
            with repo.open_blob(entry) as f:  # the front matter must fit in the first bytes
                head = f.read(_CARD_MAX_BYTES + 1024)
            meta = _front_matter(head.decode("utf-8", "replace"), truncated=entry.size > len(head))
            card = _jsonable(meta) if isinstance(meta, dict) else None
        except Exception as err:  # over a limit, invalid, or a bug: no cardData for this repo
            logger.warning(
                "Ignoring the README metadata of %s %s (README %s): %s",
                repo.repo_type,
                repo.repo_id,
                entry.oid[:12],
                _short_error(err),
            )
        with self._cards_guard:
            self._cards[entry.sha256] = card
            while len(self._cards) > _CARD_CACHE_SIZE:
                self._cards.popitem(last=False)
        return card

    # -- account -------------------------------------------------------------------------------

    def whoami(self, ctx: Ctx) -> Response:
        if ctx.user is None:
            raise HTTPError(401, _INVALID_CREDENTIALS)
        return _json(
            {
                "type": "user",
                "id": hashlib.sha1(ctx.user.encode()).hexdigest()[:24],
                "name": ctx.user,
                "fullname": ctx.user,
                "email": None,
                "emailVerified": False,
                "canPay": False,
                "isPro": False,
                "periodEnd": None,
                "avatarUrl": "",
                "orgs": [],
                "auth": {
                    "type": "access_token",
                    "accessToken": {"displayName": "hub-envs", "role": "write", "createdAt": format_date_now()},
                },
                # hub-envs' own field (the Hub has none): this server's own account manages every repo (_can_manage),
                # so a client must not apply the Hub's rule (own namespace or an organization's) to it
                "managesEveryRepo": ctx.user == self.user,
            }
        )

    def validate_yaml(self, ctx: Ctx) -> Response:
        content = self._body_json(ctx).get("content", "")
        if not isinstance(content, str):
            raise HTTPError(400, "'content' must be a string (the README text).")
        try:
            meta = _front_matter(content, strict=True)
        except ValueError as err:
            return _json({"errors": [{"message": str(err)}], "warnings": []}, status=400)
        if not meta:
            return _json({"errors": [], "warnings": [{"message": "empty or missing yaml metadata in repo card"}]})
        return _json({"errors": [], "warnings": []})

    # -- repos ---------------------------------------------------------------------------------

    def create_repo(self, ctx: Ctx) -> Response:
        user = self._require_write(ctx)
        data = self._body_json(ctx)
        name, organization = data.get("name"), data.get("organization")
        repo_type = data.get("type") or "model"
        if not isinstance(name, str) or not name:
            raise HTTPError(400, "Missing repo 'name'.")
        if repo_type not in REPO_TYPES:
            raise HTTPError(400, f"Invalid repo type {repo_type!r}: expected one of {', '.join(REPO_TYPES)}.")
        sdk = data.get("sdk") if repo_type == "space" else None  # only Spaces have an sdk
        if repo_type == "space" and sdk not in _SPACE_SDKS:
            raise HTTPError(400, f"Invalid space sdk {sdk!r}: expected one of {', '.join(_SPACE_SDKS)}.")
        if organization is not None and not isinstance(organization, str):
            raise HTTPError(400, "'organization' must be a string.")
        repo_id = f"{organization or user}/{name}"
        if user != self.user and (organization or user).lower() != user.lower():  # another account: its namespace only
            raise HTTPError(403, f"{user} cannot create repos in the namespace {organization!r}: only in {user!r}.")
        private = _requested_private(data, repo_type)
        try:
            repo = self.store.create_repo(repo_type, repo_id, author=user, private=bool(private), sdk=sdk)
        except RepoExistsError:
            # the Hub sends the url along, and `create_repo(exist_ok=True)` returns it
            existing = self.store.open(repo_type, repo_id)
            raise HTTPError(
                409, f"You already created this {repo_type} repo", extra={"url": self._repo_url(ctx, existing)}
            ) from None
        return _json({"url": self._repo_url(ctx, repo), "name": repo.repo_id, "id": repo.repo_id})

    def delete_repo(self, ctx: Ctx) -> Response:
        user = self._require_write(ctx)
        data = self._body_json(ctx)
        name, organization = data.get("name"), data.get("organization")
        if not isinstance(name, str) or not name:
            raise HTTPError(400, "Missing repo 'name'.")
        if organization is not None and not isinstance(organization, str):
            raise HTTPError(400, "'organization' must be a string.")
        repo_type = data.get("type") or "model"
        if repo_type not in REPO_TYPES:
            raise HTTPError(400, f"Invalid repo type {repo_type!r}: expected one of {', '.join(REPO_TYPES)}.")
        repo_id = f"{organization or user}/{name}"
        self._require_manage(ctx, self.store.open(repo_type, repo_id), "delete")
        self.store.delete_repo(repo_type, repo_id)
        return _json({})

    def list_repos(self, ctx: Ctx, repo_type: str) -> Response:
        author, search = ctx.query("author"), (ctx.query("search") or "").lower()
        out = []
        for meta in self.store.list_repos(repo_type):
            if meta.private and not ctx.authenticated:
                continue
            ns, name = meta.repo_id.split("/")
            if author and ns.lower() != author.lower():
                continue
            if search and search not in meta.repo_id.lower():
                continue
            try:
                repo = self.store.open(repo_type, meta.repo_id)
                out.append(self._info(ctx, repo, repo.head(), siblings=False))
            except StoreError:
                continue
            except Exception:  # one broken repo must not break the listing
                logger.exception("Leaving %s %s out of the listing", repo_type, meta.repo_id)
                continue
        try:
            limit = int(ctx.query("limit") or 0)
        except ValueError:
            raise HTTPError(400, "Invalid 'limit' query parameter.") from None
        return _json(out[:limit] if limit > 0 else out)

    def _info(self, ctx: Ctx, repo: Repo, commit: Commit, siblings: bool = True, blobs: bool = False) -> dict:
        meta = repo.meta
        card = self._card_data(repo, commit)
        tags = card.get("tags") if card else None
        info: dict[str, Any] = {
            "_id": hashlib.sha1(f"{meta.repo_type}/{meta.repo_id.lower()}".encode()).hexdigest()[:24],
            "id": meta.repo_id,
            "author": meta.repo_id.split("/")[0],
            "sha": commit.id,
            "lastModified": commit.date,
            "createdAt": meta.created_at,
            "private": meta.private,
            "gated": False,
            "disabled": False,
            "downloads": 0,
            "likes": 0,
            "tags": [str(t) for t in tags] if isinstance(tags, list) else [],
            "usedStorage": sum(e.size for e in commit.files.values()),
            "xetEnabled": False,
        }
        if card is not None:
            info["cardData"] = card
        if meta.repo_type == "space":
            info["sdk"] = meta.sdk
        if siblings:
            info["siblings"] = [{"rfilename": p, **(_sibling_blob(e) if blobs else {})} for p, e in sorted(commit.files.items())]
        return info

    def repo_info(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str | None) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision or DEFAULT_BRANCH)
        info = self._info(ctx, repo, commit, blobs=ctx.flag("blobs"))
        expand = ctx.request.query_params.getlist("expand") + ctx.request.query_params.getlist("expand[]")
        if expand:
            info = {k: v for k, v in info.items() if k in expand or k in ("_id", "id")}
        return _json(info)

    def settings(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        self._require_manage(ctx, repo, "change the settings of")
        data = self._body_json(ctx)
        if data.get("gated") not in (None, False, "false"):
            raise HTTPError(400, "Gated repos are not supported by the hub-envs server.")
        private = _requested_private(data, repo_type)
        if private is not None:
            repo.set_private(private)
        return _json({"private": repo.meta.private})

    # -- tree and files ------------------------------------------------------------------------

    def _entries(self, repo: Repo, commit: Commit, paths: list[str], expand: bool) -> list[dict]:
        folder_oids = repo.folder_oids(commit) if any(p not in commit.files for p in paths) else {}
        last = repo.last_commits(commit, paths) if expand else {}
        out = []
        for p in paths:
            entry = commit.files.get(p)
            if entry is not None:
                item = {"type": "file", "oid": entry.oid, "size": entry.size, "path": p}
                if entry.lfs:
                    item["lfs"] = {"oid": entry.sha256, "size": entry.size, "pointerSize": entry.pointer_size}
            else:
                item = {"type": "directory", "oid": folder_oids[p], "size": 0, "path": p}
            if expand and p in last:
                c = last[p]
                item["lastCommit"] = {"id": c.id, "title": c.title, "date": c.date}
            out.append(item)
        return out

    def tree(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision)
        path = path.strip("/")
        if path:
            validate_path(path)
        folders = folders_of(commit.files)
        if path and path not in folders:
            raise EntryNotFoundError(
                f"{path} does not exist on {revision!r}" if path not in commit.files else f"{path} is a file, not a folder"
            )
        prefix = f"{path}/" if path else ""
        recursive = ctx.flag("recursive")
        children = [
            p
            for p in sorted(set(commit.files) | folders)
            if p and p.startswith(prefix) and (recursive or "/" not in p[len(prefix) :])
        ]
        expand = ctx.flag("expand")
        page, headers = self._page(ctx, children, self.tree_page_size, "cursor")
        return _json(self._entries(repo, commit, page, expand), headers=headers)

    def paths_info(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision)
        raw = ctx.body
        if ctx.request.headers.get("content-type", "").startswith("application/json"):
            data = self._body_json(ctx)
            paths, expand = data.get("paths") or [], bool(data.get("expand"))
        else:
            form = parse_qs(raw.decode("utf-8", "replace"), keep_blank_values=True)
            paths = form.get("paths", [])
            expand = (form.get("expand", ["false"])[-1]).lower() in ("1", "true")
        if not isinstance(paths, list) or not all(isinstance(p, str) for p in paths):
            raise HTTPError(400, "'paths' must be a list of strings.")
        folders = folders_of(commit.files)
        found = []
        for p in paths:
            p = p.strip("/")
            validate_path(p)
            if (p in commit.files or p in folders) and p not in found:
                found.append(p)
        return _json(self._entries(repo, commit, found, expand))

    def resolve(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
        validate_path(path)  # before anything: a traversal attempt is a 400, not a 404
        repo = self._open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision)
        entry = commit.files.get(path)
        if entry is None:
            raise HTTPError(404, f"Entry not found: {path} at {revision}", "EntryNotFound", {"X-Repo-Commit": commit.id})
        name = path.rsplit("/", 1)[-1]
        ascii_name = re.sub(r'[^\x20-\x7e]|"', "_", name)
        headers = {
            "X-Repo-Commit": commit.id,
            "ETag": f'"{entry.sha256 if entry.lfs else entry.oid}"',
            "Accept-Ranges": "bytes",
            "Content-Disposition": f"inline; filename*=UTF-8''{quote(name)}; filename=\"{ascii_name}\";",
            "Content-Type": mimetypes.guess_type(name)[0] or "application/octet-stream",
        }
        if entry.lfs:  # the Hub's answer for an LFS file: its sha256 and size, as the client checks them
            headers["X-Linked-Etag"] = f'"{entry.sha256}"'
            headers["X-Linked-Size"] = str(entry.size)
        start, end, status = 0, entry.size - 1, 200
        range_header = ctx.request.headers.get("range")
        if range_header:
            parsed = _parse_range(range_header, entry.size)
            if parsed == "unsatisfiable":
                headers["Content-Range"] = f"bytes */{entry.size}"
                raise HTTPError(416, f"Range {range_header} not satisfiable for a {entry.size}-byte file.", headers=headers)
            if parsed is not None:
                start, end = parsed
                status = 206
                headers["Content-Range"] = f"bytes {start}-{end}/{entry.size}"
                if entry.lfs and ctx.method == "GET" and start > 0:  # a resumed download, typically
                    lfs_logger.info("lfs: serving bytes %d-%d of %s (%s)", start, end, entry.sha256, path)
        length = max(end - start + 1, 0)
        headers["Content-Length"] = str(length)
        if ctx.method == "HEAD":
            return Response(b"", status_code=status, headers=headers)
        handle = repo.open_blob(entry)
        handle.seek(start)

        def chunks():
            try:
                remaining = length
                while remaining > 0:
                    data = handle.read(min(_CHUNK, remaining))
                    if not data:
                        break
                    remaining -= len(data)
                    yield data
            finally:
                handle.close()

        return StreamingResponse(chunks(), status_code=status, headers=headers)

    # -- refs and history ----------------------------------------------------------------------

    def list_refs(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        refs = repo.refs()
        return _json(
            {
                "branches": [{"name": n, "ref": f"refs/heads/{n}", "targetCommit": s} for n, s in sorted(refs.branches.items())],
                "converts": [],
                "tags": [{"name": n, "ref": f"refs/tags/{n}", "targetCommit": s} for n, s in sorted(refs.tags.items())],
                "pullRequests": [
                    {"name": f"refs/pr/{pr.num}", "ref": f"refs/pr/{pr.num}", "targetCommit": pr.head}
                    for pr in sorted(repo.pull_requests(), key=lambda pr: pr.num)
                ]
                if ctx.flag("include_prs")
                else [],
            }
        )

    def list_commits(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        commits = list(repo.history(repo.resolve(revision)))
        page, headers = self._page(ctx, commits, self.commits_page_size, "p")
        formatted = "formatted" in (ctx.request.query_params.getlist("expand[]") + ctx.request.query_params.getlist("expand"))
        items = []
        for c in page:
            item: dict[str, Any] = {
                "id": c.id,
                "authors": [{"user": c.author, "avatar": ""}],
                "date": c.date,
                "title": c.title,
                "message": c.message,
            }
            if formatted:
                item["formatted"] = {"title": html.escape(c.title), "message": html.escape(c.message)}
            items.append(item)
        return _json(items, headers=headers)

    def create_branch(self, ctx: Ctx, repo_type: str, repo_id: str, branch: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        self._require_manage(ctx, repo, "create branches on")
        data = self._body_json(ctx)
        if data.get("emptyBranch"):
            raise HTTPError(400, "Empty (orphan) branches are not supported by the hub-envs server.")
        start = data.get("startingPoint")
        if start is not None and (not isinstance(start, str) or not start):
            raise HTTPError(400, f"Invalid 'startingPoint' {start!r}: expected a branch, tag or commit id (a string).")
        repo.create_branch(branch, start)
        return _json({})

    def delete_ref(self, ctx: Ctx, repo_type: str, repo_id: str, kind: str, name: str) -> Response:
        """DELETE .../branch/<name> or .../tag/<name> (``kind``)."""
        repo = self._open(ctx, repo_type, repo_id, write=True)
        self._require_manage(ctx, repo, f"delete {kind}es of" if kind == "branch" else f"delete {kind}s of")
        (repo.delete_branch if kind == "branch" else repo.delete_tag)(name)
        return _json({})

    def create_tag(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        self._require_manage(ctx, repo, "tag")
        data = self._body_json(ctx)
        tag = data.get("tag")
        if not isinstance(tag, str) or not tag:
            raise HTTPError(400, "Missing 'tag' in the request body.")
        message = data.get("message")
        repo.create_tag(tag, revision, message if isinstance(message, str) else None)
        return _json({})

    # -- uploads -------------------------------------------------------------------------------

    def preupload(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        commit = repo.resolve(revision)
        files = self._body_json(ctx).get("files")
        if not isinstance(files, list):
            raise HTTPError(400, "'files' must be a list of {path, sample, size}.")
        if len(files) > 100_000:
            raise HTTPError(400, "Too many files in one preupload request (at most 100000).")
        out = []
        for f in files:
            path = f.get("path") if isinstance(f, dict) else None
            if not isinstance(path, str):
                raise HTTPError(400, "Each file needs a 'path'.")
            validate_path(path)
            out.append(self.lfs.preupload_answer(repo, commit, f))
        return _json({"files": out, "commitOid": commit.id})

    async def commit(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        """POST /api/<type>s/<id>/commit/<branch>: an NDJSON stream, header line first, then one
        ``file`` / ``lfsFile`` / ``deletedFile`` / ``deletedFolder`` line per operation.

        The caller is authenticated and ``Content-Length`` checked before any of the body is read.
        The body is then read here, on the event loop, only to cut it into lines (each capped); the
        lines are parsed, decoded and their blobs written in a worker thread.
        """
        self._require_write(ctx)
        self._check_declared_length(ctx, self.max_body, f"the request body limit of this server ({_BODY_SETTING})")
        repo = await run_in_threadpool(self._open, ctx, repo_type, repo_id, True)
        create_pr = ctx.flag("create_pr")
        branch = revision[len("refs/heads/") :] if revision.startswith("refs/heads/") else revision
        if not create_pr:  # anyone who can read the repo may open a PR; a push needs the owner, or the PR's author
            await run_in_threadpool(self._require_push, ctx, repo, branch)
        builder = _CommitBuilder(repo, branch, check_parent=not create_pr)
        async for lines in _ndjson_lines(ctx.request, self.max_body, self.max_line):
            await run_in_threadpool(builder.feed, lines)
        header = builder.header
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
        check = None if self.allow_bytecode else _refuse_bytecode_in_env_repos
        pr_url = None
        change = Change(
            builder.operations,
            title=title,
            message=description,
            author=ctx.user or self.user,
            parent=header.get("parentCommit"),
            check=check,
        )
        if create_pr:  # the Hub opens refs/pr/N from the branch head (or from parentCommit); the branch stays
            commit, pr = await run_in_threadpool(lambda: repo.open_pull_request(branch, change))
            pr_url = f"{self._repo_url(ctx, repo)}/discussions/{pr.num}"
        else:
            commit = await run_in_threadpool(lambda: repo.commit(branch, change))
        return _json(
            {
                "success": True,
                "commitOid": commit.id,
                "commitUrl": f"{self._repo_url(ctx, repo)}/commit/{commit.id}",
                "commitMessage": title,
                "hookOutput": "",
                "pullRequestUrl": pr_url,
            }
        )

    # -- pull requests (discussions) -----------------------------------------------------------

    def _discussion(self, ctx: Ctx, repo: Repo, pr: PullRequest) -> dict:
        return {
            "num": pr.num,
            "title": pr.title,
            "author": {"name": pr.author, "type": "user"},
            "createdAt": pr.created_at,
            "status": pr.status,
            "isPullRequest": True,
            "pinned": False,
            "numComments": sum(1 for e in pr.events if e.get("type") == "comment"),
            "repo": {"name": repo.repo_id, "type": repo.repo_type},
        }

    def list_discussions(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        """The Hub's listing: ``{"discussions": [...], "count", "start", "numClosedDiscussions"}``, 50 a page (``p``)."""
        repo = self._open(ctx, repo_type, repo_id)
        prs = repo.pull_requests()
        kind, status, author = ctx.query("type"), ctx.query("status"), ctx.query("author")
        if kind == "discussion":
            prs = []
        if status == "open":
            prs = [pr for pr in prs if pr.status == "open"]
        elif status == "closed":  # the client's filters are all, open and closed: merged ones count as closed
            prs = [pr for pr in prs if pr.status != "open"]
        if author:
            prs = [pr for pr in prs if pr.author == author]
        try:
            page = max(int(ctx.query("p") or 0), 0)
        except ValueError:
            raise HTTPError(400, "Invalid 'p' query parameter: expected a page number.") from None
        size = DISCUSSIONS_PAGE_SIZE
        items = prs[page * size : (page + 1) * size]
        return _json(
            {
                "discussions": [self._discussion(ctx, repo, pr) for pr in items],
                "count": len(prs),
                "start": page * size,
                "numClosedDiscussions": sum(1 for pr in prs if pr.status != "open"),
            }
        )

    def discussion_details(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self._open(ctx, repo_type, repo_id)
        pr = repo.pull_request(num)
        changes: dict[str, Any] = {"base": f"refs/heads/{pr.target}"}
        if pr.merge_commit:
            changes["mergeCommitId"] = pr.merge_commit
        base, head = repo.load_commit(pr.base), repo.load_commit(pr.head)
        changed = sorted(p for p in set(base.files) | set(head.files) if base.files.get(p) != head.files.get(p))
        return _json(
            {
                **self._discussion(ctx, repo, pr),
                "events": list(pr.events),
                "changes": changes,
                "filesWithConflicts": [],
                "diff": "".join(f"diff --git a/{p} b/{p}\n" for p in changed),
            }
        )

    def merge_pr(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        self._require_manage(ctx, repo, "merge pull requests of")
        comment = self._body_json(ctx).get("comment")
        _, pr = repo.merge_pull_request(num, author=ctx.user or self.user, comment=comment if isinstance(comment, str) else None)
        return _json({"newStatus": pr.events[-1]})

    def discussion_status(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        data = self._body_json(ctx)
        status = data.get("status")
        if status not in ("open", "closed"):
            raise HTTPError(400, f"Invalid status {str(status)[:20]!r}: expected 'open' or 'closed'.")
        pr = repo.pull_request(num)
        if not (self._can_manage(ctx.user, repo) or ctx.user == pr.author):  # as on the Hub: the owner or the PR's author
            raise HTTPError(
                403,
                f"{ctx.user} cannot change the status of pull request #{num} on {repo.repo_id}: only "
                "the repo's owner or the pull request's author can.",
            )
        comment = data.get("comment")
        pr = repo.set_pull_request_status(
            num, status, author=ctx.user or self.user, comment=comment if isinstance(comment, str) else None
        )
        return _json({"newStatus": pr.events[-1]})


class _CommitBuilder:
    """The lines of one commit payload, applied in order in a worker thread: the header (and its
    ``parentCommit`` check, before any blob is written), then each operation, its blob stored."""

    def __init__(self, repo: Repo, branch: str, check_parent: bool = True):
        self.repo = repo
        self.branch = branch
        self.check_parent = check_parent  # not for create_pr: there parentCommit is where the PR starts
        self.header: dict | None = None
        self.operations: list = []

    def feed(self, lines: list[bytearray]) -> None:
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


# --- commit payloads ----------------------------------------------------------------------------


def _too_large(limit: int, what: str) -> HTTPError:
    return HTTPError(413, f"Request too large: over {_format_size(limit)}, {what}.")


def _format_size(n: int) -> str:
    return f"{n / MiB:g} MiB" if n >= MiB else f"{n} bytes"


async def _ndjson_lines(request: Request, max_body: int, max_line: int) -> AsyncIterator[list[bytearray]]:
    """The non-blank lines of an NDJSON body, as they arrive: one list per chunk that ends lines.

    Only cuts lines (a search in each new chunk, never in what is buffered already), so it is cheap
    on the event loop. 413 as soon as the body passes ``max_body`` or a line passes ``max_line``.
    """
    line = bytearray()
    total = 0
    async for chunk in request.stream():
        total += len(chunk)
        if total > max_body:
            raise _too_large(max_body, f"the request body limit of this server ({_BODY_SETTING})")
        done: list[bytearray] = []
        start = 0
        while True:
            i = chunk.find(b"\n", start)
            if i < 0:
                break
            line += chunk[start:i]
            if len(line) > max_line:
                raise _too_large(max_line, _LINE_LIMIT)
            if line and not line.isspace():
                done.append(line)
            line = bytearray()
            start = i + 1
        line += chunk[start:]
        if len(line) > max_line:
            raise _too_large(max_line, _LINE_LIMIT)
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
        f"Malformed commit payload: a line over {_format_size(_BIG_LINE)} must be a 'file' line with its content "
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


# --- small helpers ----------------------------------------------------------------------------


def _requested_private(data: dict, repo_type: str) -> bool | None:
    """Whether a create-repo or settings body asks for a private repo; None if it does not say.

    huggingface_hub 0.x sends ``"private": true/false``; 1.x sends ``"visibility": "public" |
    "private" | "protected"`` (``protected``, Spaces only, keeps the files private while the app is
    public; this server runs no apps, so it is private here). Both are accepted; if a body carries
    both, they must agree.
    """
    private = data.get("private")
    if private is not None and not isinstance(private, bool):
        raise HTTPError(400, f"Invalid 'private' {private!r}: expected true or false.")
    visibility = data.get("visibility")
    if visibility is None:
        return private
    if visibility not in ("public", "private", "protected"):
        raise HTTPError(400, f"Invalid 'visibility' {visibility!r}: expected 'public', 'private' or 'protected'.")
    if visibility == "protected" and repo_type != "space":
        raise HTTPError(400, "Only Spaces can be 'protected'. Set visibility to 'public' or 'private'.")
    from_visibility = visibility != "public"
    if private is not None and private != from_visibility:
        raise HTTPError(400, f"'private' ({private}) and 'visibility' ({visibility!r}) disagree: send one of them.")
    return from_visibility


def _sibling_blob(entry) -> dict:
    out: dict[str, Any] = {"size": entry.size, "blobId": entry.oid}
    if entry.lfs:
        out["lfs"] = {"sha256": entry.sha256, "size": entry.size, "pointerSize": entry.pointer_size}
    return out


def format_date_now() -> str:
    return format_date(now())


def _is_unicode(text: str) -> bool:
    """False for text holding lone surrogates (JSON's ``"\\ud800"``), which cannot be UTF-8."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _short_error(err: BaseException) -> str:
    return f"{type(err).__name__}: {str(err)[:300]}"


def _limit_bytes(value: float | None, env: str, default: float, name: str) -> int:
    """A size limit given in MiB: ``value``, else the environment variable ``env``, else ``default``."""
    if value is None:
        raw = os.environ.get(env, "").strip()
        try:
            value = float(raw) if raw else default
        except ValueError:
            raise ValueError(f"{env}={raw!r}: expected a number of MiB, such as 512.") from None
    value = float(value)
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number of MiB, got {value}.")
    return max(1, int(value * MiB))


def _is_bytecode(path: str) -> bool:
    """``.pyc``/``.pyo`` files and anything under a ``__pycache__/`` folder (any case, and with the
    trailing dots and spaces Windows drops from names)."""
    parts = [part.rstrip(" .").lower() for part in path.split("/")]
    return "__pycache__" in parts[:-1] or parts[-1].endswith((".pyc", ".pyo"))


def _refuse_bytecode_in_env_repos(files) -> None:
    """The ``check`` of commits (see :meth:`Repo.commit`): no bytecode in an env repo's tree.

    An env repo (one with a ``hub_env.json`` manifest at its root) is loaded by importing its
    ``.py`` files; a ``__pycache__/*.pyc`` beside them would run instead of the sources that the
    manifest hashes and the card shows, so it can only be planted. Other repos may hold any file.
    """
    if _ENV_MANIFEST not in files:
        return
    planted = sorted(p for p in files if _is_bytecode(p))
    if planted:
        more = f" (and {len(planted) - 1} more)" if len(planted) > 1 else ""
        raise InvalidOperationError(
            f"Refused: {planted[0]!r}{more} is compiled Python bytecode (under __pycache__/, or .pyc/.pyo) in an "
            f"env repo (one with {_ENV_MANIFEST}). Python would run it instead of the .py sources, so an env repo "
            "holds sources only: leave bytecode out of the commit (or delete it in the same commit)."
        )


class _CardLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader with limits for README metadata: no aliases (``*name``: a few hundred
    bytes of aliases expand to gigabytes once written as JSON, the "billion laughs"), and nesting
    at most ``_CARD_MAX_DEPTH`` deep (the composer recurses once per level)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            raise yaml.composer.ComposerError(
                None, None, "YAML aliases (*name) are not allowed in card metadata", self.peek_event().start_mark
            )
        if self._depth >= _CARD_MAX_DEPTH:
            raise yaml.composer.ComposerError(
                None, None, f"card metadata nested more than {_CARD_MAX_DEPTH} levels deep", self.peek_event().start_mark
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_FRONT_MATTER_RE = re.compile(r"^---[ \t]*\r?\n(.*?)(?:\r?\n)?^---[ \t]*$", flags=re.S | re.M)


def _front_matter(text: str, strict: bool = False, truncated: bool = False):
    """The YAML metadata block at the top of a README (``---`` ... ``---``), or None.

    Parsed with limits: at most ``_CARD_MAX_BYTES`` (UTF-8) of YAML, no aliases, bounded nesting.
    ``strict``: raise ValueError (with a message for the user) instead of returning None when the
    block is malformed or over a limit. ``truncated``: ``text`` is only the start of the README.
    """
    if not text.startswith("---"):
        return None
    window = text[: _CARD_MAX_BYTES + 1024]
    match = _FRONT_MATTER_RE.match(window)
    if not match:
        if not strict:
            return None
        if truncated or len(text) > len(window):
            raise ValueError(
                f"The YAML metadata block is not closed within its first {_CARD_MAX_BYTES // 1024} KiB: close it "
                "with a line '---', and keep the metadata under that size."
            )
        raise ValueError("The YAML metadata block is not closed: add a line with '---' after it.")
    block = match.group(1)
    if len(block.encode("utf-8", "replace")) > _CARD_MAX_BYTES:
        if strict:
            raise ValueError(f"The YAML metadata block is larger than {_CARD_MAX_BYTES // 1024} KiB.")
        return None
    try:
        meta = yaml.load(block, Loader=_CardLoader)  # noqa: S506 - a SafeLoader, with limits
    except yaml.YAMLError as err:
        if strict:
            raise ValueError(f"Invalid YAML in the metadata block: {err}") from None
        return None
    except (ValueError, TypeError, OverflowError, RecursionError) as err:  # e.g. a date such as 2024-02-30
        if strict:
            raise ValueError(f"Invalid value in the metadata block: {_short_error(err)}") from None
        return None
    if meta is not None and not isinstance(meta, dict):
        if strict:
            raise ValueError("The YAML metadata block must be a mapping (key: value lines).")
        return None
    return meta


def _jsonable(obj: Any) -> Any:
    """YAML data as JSON data, as the Hub reports ``cardData``: dates as ISO strings, sets as lists,
    binary as base64, keys as strings, NaN and infinities as null. (Depth is bounded by the loader.)"""
    if isinstance(obj, dict):
        return {_json_key(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [_jsonable(v) for v in sorted(obj, key=repr)]
    if obj is None or isinstance(obj, (str, bool, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (datetime.date, datetime.datetime)):
        return obj.isoformat()
    if isinstance(obj, bytes):
        return base64.b64encode(obj).decode("ascii")
    return str(obj)


def _json_key(key: Any) -> str:
    if isinstance(key, str):
        return key
    if key is None or isinstance(key, (bool, int, float)):
        return json.dumps(key)
    value = _jsonable(key)
    return value if isinstance(value, str) else json.dumps(value)


_RANGE_RE = re.compile(r"\s*bytes=(\d*)-(\d*)\s*")
_RANGE_MAX_DIGITS = 18  # more digits than any file size: read as "beyond the end", never int()-ed


def _range_int(digits: str) -> int:
    return int(digits) if len(digits) <= _RANGE_MAX_DIGITS else 10**_RANGE_MAX_DIGITS


def _parse_range(header: str, size: int):
    """``(start, end)`` inclusive for a single ``bytes=`` range, ``"unsatisfiable"``, or None to ignore it
    (RFC 9110 14.2: then the whole file is sent with 200)."""
    match = _RANGE_RE.fullmatch(header)
    if not match or (not match.group(1) and not match.group(2)):
        return None  # malformed or multi-range: ignored, the whole file is sent (RFC 9110 allows it)
    first = _range_int(match.group(1)) if match.group(1) else None
    last = _range_int(match.group(2)) if match.group(2) else None
    if first is not None:
        if last is not None and last < first:
            return None  # invalid range-spec: ignored
        if first >= size:
            return "unsatisfiable"
        return first, size - 1 if last is None else min(last, size - 1)
    if last == 0:
        return "unsatisfiable"
    if size == 0:
        return None  # a suffix of an empty file is the empty file itself: 200, no Content-Range to express
    return max(size - last, 0), size - 1


def _users_from_env(text: str) -> dict[str, str]:
    """``HUB_ENVS_SERVER_USERS="bob:TOKEN_B,carol:TOKEN_C"`` -> ``{token: name}``: more accounts on this server."""
    users = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        name, sep, token = item.partition(":")
        if not sep or not name or not token:
            raise ValueError(f"HUB_ENVS_SERVER_USERS: {item!r} is not 'name:token'.")
        users[token] = name
    return users


def create_app(root: str | os.PathLike, token: str | None = None, **options: Any) -> Starlette:
    """A Starlette app serving the repos stored under ``root``; ``options`` are :class:`HubApp`'s.

    Args:
        root: the store folder (created if missing). One server process per root.
        token: if set, writes need ``Authorization: Bearer <token>``, and so do reads of private repos.
        page_size: page size of the tree and commits lists (default 1000 and 50, like the Hub;
            env ``HUB_ENVS_SERVER_PAGE_SIZE``).
        user: the account name callers act as (default ``local``; env ``HUB_ENVS_SERVER_USER``):
            ``whoami`` returns it, and ``create_repo`` without a namespace creates repos under it.
        fsync: fsync files before moving them into place (default on; env ``HUB_ENVS_SERVER_FSYNC=0``).
        max_body_mb: largest request body, in MiB (default 2048; env ``HUB_ENVS_SERVER_MAX_BODY_MB``):
            a commit carries all its files in its body. Over it: 413.
        max_line_mb: largest line of a commit body, in MiB (default 16; env
            ``HUB_ENVS_SERVER_MAX_LINE_MB``): a line carries one inline file, base64 (4/3 of its size), and
            is held in memory while it is decoded; huggingface_hub sends files over 10 MiB through LFS,
            so its lines stay under 14 MiB. Over it: 413.
        allow_bytecode: store compiled Python bytecode in env repos too, as huggingface.co does
            (default off; env ``HUB_ENVS_SERVER_ALLOW_BYTECODE=1``): for tests of what clients do
            with a repo the real Hub would serve.
        max_lfs_mb: largest file uploaded through Git LFS, in MiB (default 51200, the Hub's 50 GB; env
            ``HUB_ENVS_SERVER_MAX_LFS_MB``). LFS files stream to disk; see :mod:`hub_envs.server.lfs`.
        users: more accounts, ``{token: name}`` (env ``HUB_ENVS_SERVER_USERS="bob:TOKEN,..."``). A caller sending
            one of these tokens acts as that name: it may write to repos of its own namespace, open pull requests
            on any repo it can read, and push to and close its own pull requests; merging needs the repo's owner (or
            the server's own ``user``, who manages every repo). Accounts need ``token`` (the owner's): without it,
            every anonymous caller would act as the owner (:class:`~hub_envs.errors.ConfigError`).
    """
    hub = HubApp(root, token, **options)
    methods = ["GET", "HEAD", "POST", "PUT", "DELETE", "PATCH"]
    app = Starlette(routes=[Route("/{path:path}", hub.endpoint, methods=methods)])
    app.state.hub = hub
    app.add_middleware(ResolveSandbox)  # /resolve/ answers: a repo's HTML or SVG runs nothing in a browser
    install_faults(app)  # no-op unless HUB_ENVS_SERVER_FAULTS is set (tests only; see faults.py)
    return app
