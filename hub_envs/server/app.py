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
* ``/preupload`` always answers ``uploadMode: "regular"``: file contents come inline, base64, in
  the NDJSON commit payload, so no LFS or Xet endpoint exists here. It also returns the ``oid`` of
  files already present, which lets the client skip no-op commits as it does against the Hub.
* A stale ``parentCommit`` is refused with 412 and the Hub's message.
* ``/resolve`` answers HEAD and GET with ``X-Repo-Commit``, ``ETag`` (the git blob sha1),
  ``Content-Length`` and ``Accept-Ranges``, and serves single ``Range`` requests with 206.
* Lists (tree, commits) are paged with a ``Link: <...>; rel="next"`` header.
* Paths that could escape a repo (``..``, absolute, ``\\``, NUL, percent-encoded variants) get 400.

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
import hashlib
import hmac
import html
import json
import logging
import mimetypes
import os
import re
from dataclasses import dataclass
from typing import Any, Callable
from urllib.parse import parse_qs, quote, unquote, urlencode

import yaml
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route

from hub_envs.server.faults import install_faults
from hub_envs.server.storage import (
    DEFAULT_BRANCH,
    REPO_TYPES,
    AddFile,
    Commit,
    DeleteFile,
    DeleteFolder,
    EntryNotFoundError,
    HubStore,
    InvalidNameError,
    InvalidOperationError,
    InvalidPathError,
    ParentMismatchError,
    RefExistsError,
    Repo,
    RepoExistsError,
    RepoNotFoundError,
    RevisionNotFoundError,
    StoreError,
    format_date,
    now,
    validate_path,
)

logger = logging.getLogger("hub_envs.server")

DEFAULT_USER = "local"
TREE_PAGE_SIZE = 1000
COMMITS_PAGE_SIZE = 50
_CHUNK = 1024 * 1024
_PLURAL = {"models": "model", "datasets": "dataset", "spaces": "space"}
_URL_PREFIX = {"model": "", "dataset": "datasets/", "space": "spaces/"}
_SPACE_SDKS = ("gradio", "streamlit", "docker", "static")
_INVALID_CREDENTIALS = "Invalid credentials in Authorization header"


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
    ):
        if fsync is None:
            fsync = os.environ.get("HUB_ENVS_SERVER_FSYNC", "1").lower() not in ("0", "false", "no")
        self.store = HubStore(root, fsync=fsync)
        self.token = token or None
        if page_size is None and os.environ.get("HUB_ENVS_SERVER_PAGE_SIZE"):
            page_size = int(os.environ["HUB_ENVS_SERVER_PAGE_SIZE"])
        if page_size is not None and page_size < 1:
            raise ValueError(f"page_size must be >= 1, got {page_size}.")
        self.tree_page_size = page_size or TREE_PAGE_SIZE
        self.commits_page_size = page_size or COMMITS_PAGE_SIZE
        self.user = user or os.environ.get("HUB_ENVS_SERVER_USER") or DEFAULT_USER

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
        except Exception as err:  # a bug: log it, answer 500 with its message
            logger.exception("Internal error on %s %s", method, request.url.path)
            return _error_response(HTTPError(500, f"Internal server error: {type(err).__name__}: {err}"))

    def _caller(self, request: Request) -> str | None:
        if self.token is None:
            return self.user  # open server: everyone is the server's user
        header = request.headers.get("authorization")
        if not header:
            return None
        if not hmac.compare_digest(header.strip().encode(), f"Bearer {self.token}".encode()):
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
        if isinstance(err, (InvalidPathError, InvalidNameError, InvalidOperationError)):
            return HTTPError(400, message)
        return HTTPError(500, message)

    # -- routing -------------------------------------------------------------------------------

    async def _route(self, ctx: Ctx) -> Response:
        segs, method = ctx.segs, ctx.method
        if segs and segs[0] == "api":
            rest = segs[1:]
            if rest == ["whoami-v2"]:
                return await self._call(ctx, {"GET": self.whoami})
            if rest == ["validate-yaml"]:
                return await self._call(ctx, {"POST": self.validate_yaml}, body=True)
            if rest == ["repos", "create"]:
                return await self._call(ctx, {"POST": self.create_repo}, body=True)
            if rest == ["repos", "delete"]:
                return await self._call(ctx, {"DELETE": self.delete_repo}, body=True)
            if len(rest) == 1 and rest[0] in _PLURAL:
                return await self._call(ctx, {"GET": lambda c: self.list_repos(c, _PLURAL[rest[0]])})
            if len(rest) >= 3 and rest[0] in _PLURAL:
                return await self._repo_api(ctx, _PLURAL[rest[0]], f"{rest[1]}/{rest[2]}", rest[3:])
            raise HTTPError(404, f"Unknown API route /{'/'.join(segs)}.")
        # /[datasets|spaces|models/]<ns>/<name>/resolve/<rev>/<path...>
        repo_type, rest = "model", segs
        if rest and rest[0] in _PLURAL:
            repo_type, rest = _PLURAL[rest[0]], rest[1:]
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
            return await self._call(
                ctx, {"POST": lambda c: self.paths_info(c, repo_type, repo_id, arg)}, body=True
            )
        if action == "refs" and arg is None:
            return await self._call(ctx, {"GET": lambda c: self.list_refs(c, repo_type, repo_id)})
        if action == "commits" and arg is not None:
            revision = "/".join(rest[1:])
            return await self._call(ctx, {"GET": lambda c: self.list_commits(c, repo_type, repo_id, revision)})
        if action == "preupload" and arg is not None:
            return await self._call(
                ctx, {"POST": lambda c: self.preupload(c, repo_type, repo_id, arg)}, body=True
            )
        if action == "commit" and arg is not None:
            if ctx.method != "POST":
                raise HTTPError(405, "Method not allowed: use POST to commit.")
            try:
                return await self.commit(ctx, repo_type, repo_id, "/".join(rest[1:]))
            except (HTTPError, StoreError):
                await _drain(ctx.request)  # read the rest, so the client gets the error, not a reset
                raise
        if action == "branch" and arg is not None:
            branch = "/".join(rest[1:])
            return await self._call(
                ctx,
                {
                    "POST": lambda c: self.create_branch(c, repo_type, repo_id, branch),
                    "DELETE": lambda c: self.delete_branch(c, repo_type, repo_id, branch),
                },
                body=True,
            )
        if action == "tag" and arg is not None:
            name = "/".join(rest[1:])
            return await self._call(
                ctx,
                {
                    "POST": lambda c: self.create_tag(c, repo_type, repo_id, name),
                    "DELETE": lambda c: self.delete_tag(c, repo_type, repo_id, name),
                },
                body=True,
            )
        if action == "settings" and arg is None:
            return await self._call(ctx, {"PUT": lambda c: self.settings(c, repo_type, repo_id)}, body=True)
        raise HTTPError(404, f"Unknown API route /{'/'.join(ctx.segs)}.")

    async def _call(self, ctx: Ctx, handlers: dict[str, Callable], body: bool = False) -> Response:
        handler = handlers.get(ctx.method)
        if handler is None and ctx.method == "HEAD":
            handler = handlers.get("GET")  # HEAD is GET without the body (uvicorn drops it)
        if handler is None:
            allowed = ", ".join(sorted(handlers))
            raise HTTPError(405, f"Method {ctx.method} not allowed here (allowed: {allowed}).", headers={"Allow": allowed})
        if body:
            ctx.body = await ctx.request.body()
        return await run_in_threadpool(handler, ctx)

    # -- helpers -------------------------------------------------------------------------------

    def _require_write(self, ctx: Ctx) -> str:
        if ctx.user is None:
            raise HTTPError(
                401,
                "Authentication required: this hub-envs server was started with --token, and write requests "
                "must send it (`Authorization: Bearer <token>`). Set HF_TOKEN to that token, or pass token=...",
            )
        return ctx.user

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

    @staticmethod
    def _card_data(repo: Repo, commit: Commit) -> dict | None:
        entry = commit.files.get("README.md")
        if entry is None or entry.size > 1_000_000:
            return None
        meta = _front_matter(repo.read_blob(entry).decode("utf-8", "replace"))
        return meta if isinstance(meta, dict) else None

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
            }
        )

    def validate_yaml(self, ctx: Ctx) -> Response:
        content = self._body_json(ctx).get("content", "")
        try:
            meta = _front_matter(str(content), strict=True)
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
        sdk = data.get("sdk")
        if repo_type == "space" and sdk not in _SPACE_SDKS:
            raise HTTPError(400, f"Invalid space sdk {sdk!r}: expected one of {', '.join(_SPACE_SDKS)}.")
        repo_id = f"{organization or user}/{name}"
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
        repo_type = data.get("type") or "model"
        self.store.delete_repo(repo_type, f"{organization or user}/{name}")
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
                head = repo.head()
            except StoreError:
                continue
            out.append(self._info(ctx, repo, head, siblings=False))
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
            info["siblings"] = [
                {"rfilename": p, **({"size": e.size, "blobId": e.oid} if blobs else {})}
                for p, e in sorted(commit.files.items())
            ]
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
        folders = _folders(commit.files)
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
        folders = _folders(commit.files)
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
            raise HTTPError(
                404, f"Entry not found: {path} at {revision}", "EntryNotFound", {"X-Repo-Commit": commit.id}
            )
        name = path.rsplit("/", 1)[-1]
        ascii_name = re.sub(r'[^\x20-\x7e]|"', "_", name)
        headers = {
            "X-Repo-Commit": commit.id,
            "ETag": f'"{entry.oid}"',
            "Accept-Ranges": "bytes",
            "Content-Disposition": f"inline; filename*=UTF-8''{quote(name)}; filename=\"{ascii_name}\";",
            "Content-Type": mimetypes.guess_type(name)[0] or "application/octet-stream",
        }
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
                "branches": [
                    {"name": n, "ref": f"refs/heads/{n}", "targetCommit": s} for n, s in sorted(refs.branches.items())
                ],
                "converts": [],
                "tags": [{"name": n, "ref": f"refs/tags/{n}", "targetCommit": s} for n, s in sorted(refs.tags.items())],
                "pullRequests": [],
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
        data = self._body_json(ctx)
        if data.get("emptyBranch"):
            raise HTTPError(400, "Empty (orphan) branches are not supported by the hub-envs server.")
        repo.create_branch(branch, data.get("startingPoint"))
        return _json({})

    def delete_branch(self, ctx: Ctx, repo_type: str, repo_id: str, branch: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        repo.delete_branch(branch)
        return _json({})

    def create_tag(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        data = self._body_json(ctx)
        tag = data.get("tag")
        if not isinstance(tag, str) or not tag:
            raise HTTPError(400, "Missing 'tag' in the request body.")
        message = data.get("message")
        repo.create_tag(tag, revision, message if isinstance(message, str) else None)
        return _json({})

    def delete_tag(self, ctx: Ctx, repo_type: str, repo_id: str, tag: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        repo.delete_tag(tag)
        return _json({})

    # -- uploads -------------------------------------------------------------------------------

    def preupload(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self._open(ctx, repo_type, repo_id, write=True)
        commit = repo.resolve(revision)
        files = self._body_json(ctx).get("files")
        if not isinstance(files, list):
            raise HTTPError(400, "'files' must be a list of {path, sample, size}.")
        out = []
        for f in files:
            path = f.get("path") if isinstance(f, dict) else None
            if not isinstance(path, str):
                raise HTTPError(400, "Each file needs a 'path'.")
            validate_path(path)
            existing = commit.files.get(path)
            out.append(
                {
                    "path": path,
                    "uploadMode": "regular",
                    "shouldIgnore": False,
                    "oid": existing.oid if existing else None,
                }
            )
        return _json({"files": out, "commitOid": commit.id})

    async def commit(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        """POST /api/<type>s/<id>/commit/<branch>: an NDJSON stream, header line first, then one
        ``file`` / ``lfsFile`` / ``deletedFile`` / ``deletedFolder`` line per operation."""
        repo = await run_in_threadpool(self._open, ctx, repo_type, repo_id, True)
        if ctx.flag("create_pr"):
            raise HTTPError(400, "Pull requests (create_pr=True) are not supported by the hub-envs server.")
        branch = revision[len("refs/heads/") :] if revision.startswith("refs/heads/") else revision
        header: dict | None = None
        operations: list = []
        async for line in _ndjson_lines(ctx.request):
            try:
                item = json.loads(line)
                key, value = item["key"], item["value"]
            except (ValueError, KeyError, TypeError):
                raise HTTPError(400, "Malformed commit payload: each line must be {\"key\": ..., \"value\": ...}.") from None
            if header is None:
                if key != "header" or not isinstance(value, dict):
                    raise HTTPError(400, "Malformed commit payload: the first line must be the 'header'.")
                header = value
                parent = header.get("parentCommit")
                if parent is not None:
                    if not isinstance(parent, str) or not re.fullmatch(r"[0-9a-fA-F]{5,40}", parent):
                        raise HTTPError(400, f"Invalid parentCommit {parent!r}: expected 5 to 40 hex digits.")
                    head = await run_in_threadpool(repo.resolve, branch)
                    if not head.id.startswith(parent.lower()):  # fail before writing any blob
                        raise ParentMismatchError(
                            "The branch was updated since you opened this page. Please refresh and try again."
                        )
                continue
            if not isinstance(value, dict) or not isinstance(value.get("path"), str):
                raise HTTPError(400, f"Malformed commit payload: a {key!r} line needs a 'path'.")
            path = value["path"]
            if key == "file":
                validate_path(path)
                content = value.get("content", "")
                encoding = value.get("encoding", "utf-8")
                try:
                    data = base64.b64decode(content, validate=True) if encoding == "base64" else str(content).encode()
                except (binascii.Error, ValueError):
                    raise HTTPError(400, f"Malformed commit payload: the content of {path!r} is not valid base64.") from None
                entry = await run_in_threadpool(repo.write_blob, data)
                operations.append(AddFile(path, entry))
            elif key == "lfsFile":
                validate_path(path)
                oid = str(value.get("oid", ""))
                if value.get("algo", "sha256") != "sha256" or not repo.has_blob(oid):
                    raise HTTPError(
                        400,
                        f"LFS object {oid} for {path!r} is not on this server: the hub-envs server takes file "
                        "contents inline (preupload answers uploadMode 'regular').",
                    )
                operations.append(AddFile(path, await run_in_threadpool(repo.blob_entry, oid)))
            elif key == "deletedFile":
                operations.append(DeleteFile(path))
            elif key == "deletedFolder":
                operations.append(DeleteFolder(path.rstrip("/")))
            else:
                raise HTTPError(
                    400, f"Malformed commit payload: unknown key {key!r} (expected file, lfsFile, deletedFile, deletedFolder)."
                )
        if header is None:
            raise HTTPError(400, "Malformed commit payload: empty body; send a 'header' line then the operations.")
        title = header.get("summary")
        if not isinstance(title, str) or not title.strip():
            raise HTTPError(400, "The commit summary (commit_message) cannot be empty.")
        description = header.get("description") or ""
        commit = await run_in_threadpool(
            lambda: repo.commit(
                branch,
                operations,
                title=title,
                message=str(description),
                author=ctx.user or self.user,
                parent=header.get("parentCommit"),
            )
        )
        return _json(
            {
                "success": True,
                "commitOid": commit.id,
                "commitUrl": f"{self._repo_url(ctx, repo)}/commit/{commit.id}",
                "commitMessage": title,
                "hookOutput": "",
                "pullRequestUrl": None,
            }
        )


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


def format_date_now() -> str:
    return format_date(now())


def _folders(files) -> set[str]:
    out: set[str] = set()
    for p in files:
        parts = p.split("/")
        out.update("/".join(parts[:i]) for i in range(1, len(parts)))
    return out


def _front_matter(text: str, strict: bool = False):
    """The YAML metadata block at the top of a README (``---`` ... ``---``), or None."""
    if not text.startswith("---"):
        return None
    match = re.match(r"^---[ \t]*\r?\n(.*?)(?:\r?\n)?^---[ \t]*$", text, flags=re.S | re.M)
    if not match:
        if strict:
            raise ValueError("The YAML metadata block is not closed: add a line with '---' after it.")
        return None
    try:
        meta = yaml.safe_load(match.group(1))
    except yaml.YAMLError as err:
        if strict:
            raise ValueError(f"Invalid YAML in the metadata block: {err}") from None
        return None
    if meta is not None and not isinstance(meta, dict):
        if strict:
            raise ValueError("The YAML metadata block must be a mapping (key: value lines).")
        return None
    return meta


def _parse_range(header: str, size: int):
    """``(start, end)`` inclusive for a single ``bytes=`` range, ``"unsatisfiable"``, or None to ignore it."""
    match = re.fullmatch(r"\s*bytes=(\d*)-(\d*)\s*", header)
    if not match or (not match.group(1) and not match.group(2)):
        return None  # malformed or multi-range: ignored, the whole file is sent (RFC 9110 allows it)
    first, last = match.group(1), match.group(2)
    if first:
        start = int(first)
        end = min(int(last), size - 1) if last else size - 1
        if last and int(last) < start:
            return None
        if start >= size:
            return "unsatisfiable"
        return start, end
    suffix = int(last)
    if suffix == 0:
        return "unsatisfiable"
    return max(size - suffix, 0), size - 1


async def _drain(request: Request) -> None:
    try:
        async for _ in request.stream():
            pass
    except Exception:  # already consumed, or the client went away
        pass


async def _ndjson_lines(request: Request):
    buffer = bytearray()
    async for chunk in request.stream():
        buffer.extend(chunk)
        while True:
            i = buffer.find(b"\n")
            if i < 0:
                break
            line = bytes(buffer[:i]).strip()
            del buffer[: i + 1]
            if line:
                yield line
    if bytes(buffer).strip():
        yield bytes(buffer).strip()


def create_app(
    root: str | os.PathLike,
    token: str | None = None,
    *,
    page_size: int | None = None,
    user: str | None = None,
    fsync: bool | None = None,
) -> Starlette:
    """A Starlette app serving the repos stored under ``root``.

    Args:
        root: the store folder (created if missing). One server process per root.
        token: if set, writes need ``Authorization: Bearer <token>``, and so do reads of private repos.
        page_size: page size of the tree and commits lists (default 1000 and 50, like the Hub;
            env ``HUB_ENVS_SERVER_PAGE_SIZE``).
        user: the account name callers act as (default ``local``; env ``HUB_ENVS_SERVER_USER``):
            ``whoami`` returns it, and ``create_repo`` without a namespace creates repos under it.
        fsync: fsync files before moving them into place (default on; env ``HUB_ENVS_SERVER_FSYNC=0``).
    """
    hub = HubApp(root, token, page_size=page_size, user=user, fsync=fsync)
    methods = ["GET", "HEAD", "POST", "PUT", "DELETE", "PATCH"]
    app = Starlette(routes=[Route("/{path:path}", hub.endpoint, methods=methods)])
    app.state.hub = hub
    install_faults(app)  # no-op unless HUB_ENVS_SERVER_FAULTS is set (tests only; see faults.py)
    return app
