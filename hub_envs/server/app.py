"""The HTTP routes of the loopback Hub server: the subset of the Hugging Face Hub API that ``huggingface_hub``
(0.34/0.35 and 1.x) uses to create repos, commit, tag, list and download, and the web pages beside it.

How the protocol matches huggingface.co's, and the limits that keep a hostile client from taking the server
down: ``docs/server.md``.

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

import hashlib
import html
import logging
import mimetypes
import os
import re
from typing import Any
from urllib.parse import parse_qs, quote, unquote

import anyio
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route

from hub_envs.errors import ConfigError
from hub_envs.server.access import INVALID_CREDENTIALS, Access, users_from_env
from hub_envs.server.cards import CardData, front_matter
from hub_envs.server.commit_payload import (
    DEFAULT_MAX_LINE_MB,
    CommitBuilder,
    ndjson_lines,
    refuse_bytecode_in_env_repos,
)
from hub_envs.server.faults import install_faults
from hub_envs.server.httputil import (
    BODY_SETTING,
    MAX_JSON_BODY,
    PLURAL,
    Ctx,
    HTTPError,
    body_json,
    call,
    check_declared_length,
    error_response,
    json_response,
    limit_bytes,
    paginate,
    parse_range,
    repo_url,
    require_user,
)
from hub_envs.server.lfs import LfsRoutes
from hub_envs.server.lfs import logger as lfs_logger
from hub_envs.server.pages import Pages, ResolveSandbox
from hub_envs.server.storage import (
    DEFAULT_BRANCH,
    REPO_TYPES,
    Commit,
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
#: The default cap (MiB) of a request body: a commit carries all of its inline files, read line by line.
DEFAULT_MAX_BODY_MB = 2048.0
_CHUNK = 1024 * 1024
_SPACE_SDKS = ("gradio", "streamlit", "docker", "static")
_INTERNAL_ERROR = "Internal server error: the request failed on the server (the details are in the server's log)."
_PAGE_THREADS = 8  # web pages render in at most this many threads: a slow page never takes the API's threads


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
        token = token or None
        user = user or os.environ.get("HUB_ENVS_SERVER_USER") or DEFAULT_USER
        # more accounts (token -> name): each owns its own namespace only; see Access.can_manage
        users = dict(users) if users is not None else users_from_env(os.environ.get("HUB_ENVS_SERVER_USERS", ""))
        if users and token is None:  # an anonymous caller would act as the owner, who manages every repo
            names = ", ".join(sorted(set(users.values())))
            raise ConfigError(
                f"Accounts are configured (HUB_ENVS_SERVER_USERS: {names}) but the server has no token: every request "
                f"without a token would act as the owner account {user!r}, which may create repos in any namespace "
                f"and delete any repo. Start it with --token=<the owner's token> (clients of {user!r} set HF_TOKEN "
                "to it), or without HUB_ENVS_SERVER_USERS for a single-account server open to anyone."
            )
        self.store = HubStore(root, fsync=fsync)
        self.access = Access(self.store, token, user, users)
        self.user = user
        if page_size is None and os.environ.get("HUB_ENVS_SERVER_PAGE_SIZE"):
            page_size = int(os.environ["HUB_ENVS_SERVER_PAGE_SIZE"])
        if page_size is not None and page_size < 1:
            raise ValueError(f"page_size must be >= 1, got {page_size}.")
        self.tree_page_size = page_size or TREE_PAGE_SIZE
        self.commits_page_size = page_size or COMMITS_PAGE_SIZE
        self.max_body = limit_bytes(max_body_mb, "HUB_ENVS_SERVER_MAX_BODY_MB", DEFAULT_MAX_BODY_MB, "max_body_mb")
        self.max_line = limit_bytes(max_line_mb, "HUB_ENVS_SERVER_MAX_LINE_MB", DEFAULT_MAX_LINE_MB, "max_line_mb")
        if self.max_body < MAX_JSON_BODY:  # JSON bodies: 32 MiB, or the body cap when it is lower
            self.json_limit = (self.max_body, f"the request body limit of this server ({BODY_SETTING})")
        else:
            self.json_limit = (MAX_JSON_BODY, "the limit of JSON request bodies on this server")
        if allow_bytecode is None:
            allow_bytecode = os.environ.get("HUB_ENVS_SERVER_ALLOW_BYTECODE", "").lower() in ("1", "true", "yes")
        self.allow_bytecode = allow_bytecode  # as huggingface.co does: to test clients against it
        self.cards = CardData()  # README metadata, for repo info and the pages
        self.pages = Pages(self.store, self.access, self.cards)  # the web pages
        self._page_threads: anyio.CapacityLimiter | None = None  # pages wait for these, never for the API's threads
        self.lfs = LfsRoutes(self.store, self.access, max_lfs_mb=max_lfs_mb)  # Git LFS: preupload rules, batch API, uploads

    # -- entry point ---------------------------------------------------------------------------

    async def endpoint(self, request: Request) -> Response:
        """The ASGI endpoint of every request: parse it, route it, answer errors as the Hub does.

        Args:
            request: the request.

        Returns:
            The answer; a store or HTTP error becomes the Hub's error answer, a bug a generic 500 (details logged).
        """
        method = request.method
        raw = request.scope.get("raw_path") or request.url.path.encode()
        segs = [unquote(s) for s in raw.decode("latin-1").split("/")[1:]]
        if segs and segs[-1] == "" and len(segs) > 1:
            segs = segs[:-1]
        try:
            ctx = Ctx(
                request,
                method,
                segs,
                self.access.caller(request),
                body_limit=self.json_limit[0],
                body_limit_name=self.json_limit[1],
            )
            return await self._route(ctx)
        except HTTPError as err:
            return error_response(err)
        except StoreError as err:
            return error_response(self._store_error(err, request))
        except ClientDisconnect:  # the client went away mid-body: nobody reads this answer
            return error_response(HTTPError(400, "Client disconnected before sending the whole request body."))
        except Exception:  # a bug: log it, answer 500 without its details (paths, internals)
            logger.exception("Internal error on %s %s", method, request.url.path)
            return error_response(HTTPError(500, _INTERNAL_ERROR))

    def _store_error(self, err: StoreError, request: Request) -> HTTPError:
        message = str(err)
        if isinstance(err, RepoNotFoundError):
            anonymous = self.access.token is not None and not request.headers.get("authorization")
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
            return await call(ctx, {"GET": lambda c: self.pages.handle(c, page)}, threads=self._page_threads)
        if segs and segs[0] == "api":
            rest = segs[1:]
            if rest == ["whoami-v2"]:
                return await call(ctx, {"GET": self._whoami})
            if rest == ["validate-yaml"]:
                return await call(ctx, {"POST": self._validate_yaml}, body=True, write=True)
            if rest == ["repos", "create"]:
                return await call(ctx, {"POST": self._create_repo}, body=True, write=True)
            if rest == ["repos", "delete"]:
                return await call(ctx, {"DELETE": self._delete_repo}, body=True, write=True)
            if len(rest) == 1 and rest[0] in PLURAL:
                return await call(ctx, {"GET": lambda c: self._list_repos(c, PLURAL[rest[0]])})
            if len(rest) >= 3 and rest[0] in PLURAL:
                return await self._repo_api(ctx, PLURAL[rest[0]], f"{rest[1]}/{rest[2]}", rest[3:])
            raise HTTPError(404, f"Unknown API route /{'/'.join(segs)}.")
        # /[datasets|spaces|models/]<ns>/<name>/resolve/<rev>/<path...>
        repo_type, rest = "model", segs
        if rest and rest[0] in PLURAL:
            repo_type, rest = PLURAL[rest[0]], rest[1:]
        if len(rest) >= 4 and rest[1].endswith(".git") and rest[2:4] == ["info", "lfs"]:  # Git LFS
            return await self.lfs.route(ctx, repo_type, f"{rest[0]}/{rest[1][: -len('.git')]}", rest[4:])
        if len(rest) >= 4 and rest[2] == "resolve":
            repo_id, revision, path = f"{rest[0]}/{rest[1]}", rest[3], "/".join(rest[4:])
            handlers = {m: (lambda c: self._resolve(c, repo_type, repo_id, revision, path)) for m in ("GET", "HEAD")}
            return await call(ctx, handlers)
        raise HTTPError(404, f"Not found: /{'/'.join(segs)}.")

    async def _repo_api(self, ctx: Ctx, repo_type: str, repo_id: str, rest: list[str]) -> Response:
        action = rest[0] if rest else None
        arg = rest[1] if len(rest) > 1 else None
        if action is None:
            return await call(ctx, {"GET": lambda c: self._repo_info(c, repo_type, repo_id, None)})
        if action == "revision" and arg is not None:
            revision = "/".join(rest[1:])
            return await call(ctx, {"GET": lambda c: self._repo_info(c, repo_type, repo_id, revision)})
        if action == "tree" and arg is not None:
            path = "/".join(rest[2:])
            return await call(ctx, {"GET": lambda c: self._tree(c, repo_type, repo_id, arg, path)})
        if action == "paths-info" and arg is not None:
            return await call(ctx, {"POST": lambda c: self._paths_info(c, repo_type, repo_id, arg)}, body=True)
        if action == "refs" and arg is None:
            return await call(ctx, {"GET": lambda c: self._list_refs(c, repo_type, repo_id)})
        if action == "commits" and arg is not None:
            revision = "/".join(rest[1:])
            return await call(ctx, {"GET": lambda c: self._list_commits(c, repo_type, repo_id, revision)})
        if action == "preupload" and arg is not None:
            return await call(ctx, {"POST": lambda c: self._preupload(c, repo_type, repo_id, arg)}, body=True, write=True)
        if action == "commit" and arg is not None:
            if ctx.method != "POST":
                raise HTTPError(405, "Method not allowed: use POST to commit.")
            # An error answered before the whole body is read is fine: the server (uvicorn) reads
            # and discards the rest, so the client still gets the answer.
            return await self._commit(ctx, repo_type, repo_id, "/".join(rest[1:]))
        if action in ("branch", "tag") and arg is not None:  # create (POST) or delete (DELETE) a ref
            ref = "/".join(rest[1:])
            create = self._create_branch if action == "branch" else self._create_tag
            return await call(
                ctx,
                {
                    "POST": lambda c: create(c, repo_type, repo_id, ref),
                    "DELETE": lambda c: self._delete_ref(c, repo_type, repo_id, action, ref),
                },
                body=True,
                write=True,
            )
        if action == "discussions":
            return await self._discussions_api(ctx, repo_type, repo_id, rest[1:])
        if action in ("xet-write-token", "xet-read-token"):  # Xet is not offered: say what to do instead
            return await call(ctx, {m: self.lfs.no_xet for m in ("GET", "POST")})
        if action == "settings" and arg is None:
            return await call(ctx, {"PUT": lambda c: self._settings(c, repo_type, repo_id)}, body=True, write=True)
        raise HTTPError(404, f"Unknown API route /{'/'.join(ctx.segs)}.")

    async def _discussions_api(self, ctx: Ctx, repo_type: str, repo_id: str, rest: list[str]) -> Response:
        """``/discussions`` (list), ``/discussions/<num>`` (details), ``/discussions/<num>/merge`` and ``/status``."""
        if not rest:
            return await call(ctx, {"GET": lambda c: self._list_discussions(c, repo_type, repo_id)})
        if not rest[0].isdigit() or len(rest[0]) > 9 or int(rest[0]) < 1:
            raise HTTPError(400, f"Invalid discussion number {rest[0][:20]!r}: expected a positive integer.")
        num = int(rest[0])
        if len(rest) == 1:
            return await call(ctx, {"GET": lambda c: self._discussion_details(c, repo_type, repo_id, num)})
        if len(rest) == 2 and rest[1] == "merge":
            return await call(ctx, {"POST": lambda c: self._merge_pr(c, repo_type, repo_id, num)}, body=True, write=True)
        if len(rest) == 2 and rest[1] == "status":
            return await call(ctx, {"POST": lambda c: self._discussion_status(c, repo_type, repo_id, num)}, body=True, write=True)
        raise HTTPError(404, f"Unknown API route /{'/'.join(ctx.segs)}: this server has pull requests, not comments.")

    # -- account -------------------------------------------------------------------------------

    def _whoami(self, ctx: Ctx) -> Response:
        if ctx.user is None:
            raise HTTPError(401, INVALID_CREDENTIALS)
        return json_response(
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

    def _validate_yaml(self, ctx: Ctx) -> Response:
        content = body_json(ctx).get("content", "")
        if not isinstance(content, str):
            raise HTTPError(400, "'content' must be a string (the README text).")
        try:
            meta = front_matter(content, strict=True)
        except ValueError as err:
            return json_response({"errors": [{"message": str(err)}], "warnings": []}, status=400)
        if not meta:
            return json_response({"errors": [], "warnings": [{"message": "empty or missing yaml metadata in repo card"}]})
        return json_response({"errors": [], "warnings": []})

    # -- repos ---------------------------------------------------------------------------------

    def _create_repo(self, ctx: Ctx) -> Response:
        user = require_user(ctx)
        data = body_json(ctx)
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
                409,
                f"You already created this {repo_type} repo",
                extra={"url": repo_url(ctx.base_url, existing.repo_type, existing.repo_id)},
            ) from None
        return json_response(
            {"url": repo_url(ctx.base_url, repo.repo_type, repo.repo_id), "name": repo.repo_id, "id": repo.repo_id}
        )

    def _delete_repo(self, ctx: Ctx) -> Response:
        user = require_user(ctx)
        data = body_json(ctx)
        name, organization = data.get("name"), data.get("organization")
        if not isinstance(name, str) or not name:
            raise HTTPError(400, "Missing repo 'name'.")
        if organization is not None and not isinstance(organization, str):
            raise HTTPError(400, "'organization' must be a string.")
        repo_type = data.get("type") or "model"
        if repo_type not in REPO_TYPES:
            raise HTTPError(400, f"Invalid repo type {repo_type!r}: expected one of {', '.join(REPO_TYPES)}.")
        repo_id = f"{organization or user}/{name}"
        self.access.require_manage(ctx, self.store.open(repo_type, repo_id), "delete")
        self.store.delete_repo(repo_type, repo_id)
        return json_response({})

    def _list_repos(self, ctx: Ctx, repo_type: str) -> Response:
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
        return json_response(out[:limit] if limit > 0 else out)

    def _info(self, ctx: Ctx, repo: Repo, commit: Commit, siblings: bool = True, blobs: bool = False) -> dict:
        meta = repo.meta
        card = self.cards.get(repo, commit)
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

    def _repo_info(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str | None) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision or DEFAULT_BRANCH)
        info = self._info(ctx, repo, commit, blobs=ctx.flag("blobs"))
        expand = ctx.request.query_params.getlist("expand") + ctx.request.query_params.getlist("expand[]")
        if expand:
            info = {k: v for k, v in info.items() if k in expand or k in ("_id", "id")}
        return json_response(info)

    def _settings(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        self.access.require_manage(ctx, repo, "change the settings of")
        data = body_json(ctx)
        if data.get("gated") not in (None, False, "false"):
            raise HTTPError(400, "Gated repos are not supported by the hub-envs server.")
        private = _requested_private(data, repo_type)
        if private is not None:
            repo.set_private(private)
        return json_response({"private": repo.meta.private})

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

    def _tree(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
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
        page, headers = paginate(ctx, children, self.tree_page_size, "cursor")
        return json_response(self._entries(repo, commit, page, expand), headers=headers)

    def _paths_info(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
        commit = repo.resolve(revision)
        raw = ctx.body
        if ctx.request.headers.get("content-type", "").startswith("application/json"):
            data = body_json(ctx)
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
        return json_response(self._entries(repo, commit, found, expand))

    def _resolve(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
        validate_path(path)  # before anything: a traversal attempt is a 400, not a 404
        repo = self.access.open(ctx, repo_type, repo_id)
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
            parsed = parse_range(range_header, entry.size)
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

    def _list_refs(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
        refs = repo.refs()
        return json_response(
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

    def _list_commits(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
        commits = list(repo.history(repo.resolve(revision)))
        page, headers = paginate(ctx, commits, self.commits_page_size, "p")
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
        return json_response(items, headers=headers)

    def _create_branch(self, ctx: Ctx, repo_type: str, repo_id: str, branch: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        self.access.require_manage(ctx, repo, "create branches on")
        data = body_json(ctx)
        if data.get("emptyBranch"):
            raise HTTPError(400, "Empty (orphan) branches are not supported by the hub-envs server.")
        start = data.get("startingPoint")
        if start is not None and (not isinstance(start, str) or not start):
            raise HTTPError(400, f"Invalid 'startingPoint' {start!r}: expected a branch, tag or commit id (a string).")
        repo.create_branch(branch, start)
        return json_response({})

    def _delete_ref(self, ctx: Ctx, repo_type: str, repo_id: str, kind: str, name: str) -> Response:
        """DELETE .../branch/<name> or .../tag/<name> (``kind``)."""
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        self.access.require_manage(ctx, repo, f"delete {kind}es of" if kind == "branch" else f"delete {kind}s of")
        (repo.delete_branch if kind == "branch" else repo.delete_tag)(name)
        return json_response({})

    def _create_tag(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        self.access.require_manage(ctx, repo, "tag")
        data = body_json(ctx)
        tag = data.get("tag")
        if not isinstance(tag, str) or not tag:
            raise HTTPError(400, "Missing 'tag' in the request body.")
        message = data.get("message")
        repo.create_tag(tag, revision, message if isinstance(message, str) else None)
        return json_response({})

    # -- uploads -------------------------------------------------------------------------------

    def _preupload(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        commit = repo.resolve(revision)
        files = body_json(ctx).get("files")
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
        return json_response({"files": out, "commitOid": commit.id})

    async def _commit(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        """POST /api/<type>s/<id>/commit/<branch>: an NDJSON stream, header line first, then one
        ``file`` / ``lfsFile`` / ``deletedFile`` / ``deletedFolder`` line per operation.

        The caller is authenticated and ``Content-Length`` checked before any of the body is read.
        The body is then read here, on the event loop, only to cut it into lines (each capped); the
        lines are parsed, decoded and their blobs written in a worker thread.
        """
        require_user(ctx)
        check_declared_length(ctx, self.max_body, f"the request body limit of this server ({BODY_SETTING})")
        repo = await run_in_threadpool(self.access.open, ctx, repo_type, repo_id, True)
        create_pr = ctx.flag("create_pr")
        branch = revision[len("refs/heads/") :] if revision.startswith("refs/heads/") else revision
        if not create_pr:  # anyone who can read the repo may open a PR; a push needs the owner, or the PR's author
            await run_in_threadpool(self.access.require_push, ctx, repo, branch)
        builder = CommitBuilder(repo, branch, check_parent=not create_pr)
        async for lines in ndjson_lines(ctx.request, self.max_body, self.max_line):
            await run_in_threadpool(builder.feed, lines)
        change = builder.change(ctx.user or self.user, None if self.allow_bytecode else refuse_bytecode_in_env_repos)
        pr_url = None
        if create_pr:  # the Hub opens refs/pr/N from the branch head (or from parentCommit); the branch stays
            commit, pr = await run_in_threadpool(lambda: repo.open_pull_request(branch, change))
            pr_url = f"{repo_url(ctx.base_url, repo.repo_type, repo.repo_id)}/discussions/{pr.num}"
        else:
            commit = await run_in_threadpool(lambda: repo.commit(branch, change))
        return json_response(
            {
                "success": True,
                "commitOid": commit.id,
                "commitUrl": f"{repo_url(ctx.base_url, repo.repo_type, repo.repo_id)}/commit/{commit.id}",
                "commitMessage": change.title,
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

    def _list_discussions(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        """The Hub's listing: ``{"discussions": [...], "count", "start", "numClosedDiscussions"}``, 50 a page (``p``)."""
        repo = self.access.open(ctx, repo_type, repo_id)
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
        return json_response(
            {
                "discussions": [self._discussion(ctx, repo, pr) for pr in items],
                "count": len(prs),
                "start": page * size,
                "numClosedDiscussions": sum(1 for pr in prs if pr.status != "open"),
            }
        )

    def _discussion_details(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id)
        pr = repo.pull_request(num)
        changes: dict[str, Any] = {"base": f"refs/heads/{pr.target}"}
        if pr.merge_commit:
            changes["mergeCommitId"] = pr.merge_commit
        base, head = repo.load_commit(pr.base), repo.load_commit(pr.head)
        changed = sorted(p for p in set(base.files) | set(head.files) if base.files.get(p) != head.files.get(p))
        return json_response(
            {
                **self._discussion(ctx, repo, pr),
                "events": list(pr.events),
                "changes": changes,
                "filesWithConflicts": [],
                "diff": "".join(f"diff --git a/{p} b/{p}\n" for p in changed),
            }
        )

    def _merge_pr(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        self.access.require_manage(ctx, repo, "merge pull requests of")
        comment = body_json(ctx).get("comment")
        _, pr = repo.merge_pull_request(num, author=ctx.user or self.user, comment=comment if isinstance(comment, str) else None)
        return json_response({"newStatus": pr.events[-1]})

    def _discussion_status(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        repo = self.access.open(ctx, repo_type, repo_id, write=True)
        data = body_json(ctx)
        status = data.get("status")
        if status not in ("open", "closed"):
            raise HTTPError(400, f"Invalid status {str(status)[:20]!r}: expected 'open' or 'closed'.")
        pr = repo.pull_request(num)
        if not (self.access.can_manage(ctx.user, repo) or ctx.user == pr.author):  # as on the Hub: the owner or the PR's author
            raise HTTPError(
                403,
                f"{ctx.user} cannot change the status of pull request #{num} on {repo.repo_id}: only "
                "the repo's owner or the pull request's author can.",
            )
        comment = data.get("comment")
        pr = repo.set_pull_request_status(
            num, status, author=ctx.user or self.user, comment=comment if isinstance(comment, str) else None
        )
        return json_response({"newStatus": pr.events[-1]})


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
