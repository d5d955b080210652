"""The web pages of the loopback Hub: what a person sees who points a browser at ``hub-envs serve``.

Server-rendered HTML (Jinja templates under ``templates/``, static files under ``static/``, no build step):
the home page, each repo's files, card and reproductions matrix, a file, the history, the dataset viewer
(``/{user}/{repo}/episodes``) and the pull requests (``/{user}/{repo}/discussions``, for browsers). What each
page shows and why it is safe: ``docs/server.md``.

Example:
    >>> import tempfile
    >>> from starlette.testclient import TestClient
    >>> from hub_envs.server import create_app
    >>> client = TestClient(create_app(tempfile.mkdtemp()))
    >>> _ = client.post("/api/repos/create", json={"name": "pendulum", "organization": "alice"})
    >>> r = client.get("/", headers={"Accept": "text/html"})
    >>> r.status_code, r.headers["content-type"], "alice/pendulum" in r.text
    (200, 'text/html; charset=utf-8', True)
    >>> client.get("/").status_code  # an API client asking for "/" still gets the API's answer
    404
    >>> r = client.get("/alice/nope")
    >>> r.status_code, "alice/nope" in r.text
    (404, True)
"""

from __future__ import annotations

import json
import logging
import mimetypes
import posixpath
import struct
import threading
import zlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlencode

import jinja2
from pygments.formatters import HtmlFormatter
from starlette.responses import Response

from hub_envs.server.access import Access
from hub_envs.server.cards import CardData, card_fields, card_tags, card_title, eval_results, strip_front_matter
from hub_envs.server.diffs import changes
from hub_envs.server.episodes import INFO, PREFIXES, DatasetUnreadable, EpisodeReader, find_dataset
from hub_envs.server.formats import ENV_MANIFEST
from hub_envs.server.httputil import PLURAL, URL_PREFIX, Ctx
from hub_envs.server.rendering import CardNotRendered, CardRenderer, Links, as_text, highlight_file, plain_card
from hub_envs.server.reproductions import Records, is_record, matrix
from hub_envs.server.storage import (
    DEFAULT_BRANCH,
    Commit,
    EntryNotFoundError,
    HubStore,
    InvalidNameError,
    InvalidPathError,
    PullRequestNotFoundError,
    Repo,
    RepoNotFoundError,
    RevisionNotFoundError,
    StoreError,
    folders_of,
    validate_path,
)
from hub_envs.server.suites import SuiteTables

logger = logging.getLogger("hub_envs.server")

HERE = Path(__file__).resolve().parent
STATIC_PREFIX = "/_hub/static/"  # "_hub" cannot be a namespace: repo ids start with a letter or digit

#: Every page: scripts, styles, images, media and fetches (the dataset viewer's data) from this server only; no
#: inline script or style, no plugins, no frames, forms post back here only.
PAGE_CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; media-src 'self'; connect-src 'self'; "
    "form-action 'self'; base-uri 'none'; frame-ancestors 'none'"
)
#: ``/resolve/`` answers: repo files opened in the browser (an .html or .svg a repo author wrote)
#: run nothing and load nothing. Clients of the API ignore it.
RESOLVE_CSP = "default-src 'none'; img-src 'self'; media-src 'self'; style-src 'unsafe-inline'; sandbox"
_PAGE_HEADERS = {
    "Content-Security-Policy": PAGE_CSP,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
    "Cache-Control": "no-cache",
}

MAX_CARD_BYTES = 512 * 1024  # the card rendered: at most this much Markdown (the rest is cut, and said)
MAX_TEXT_BYTES = 1024 * 1024  # a text file shown: at most this large
RECENT_COMMITS = 8
COMMITS_PAGE = 50
EPISODES_PAGE = 100  # episodes listed per page
_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".gif", ".webp", ".bmp", ".svg", ".ico"}
_VIDEO_EXT = {".mp4", ".webm", ".ogv"}
_THUMBNAIL = "media/rollout.gif"  # what push_env renders for the card
_ROLLOUT_VIDEO = "media/rollout.mp4"  # beside it when the dataset stores video: shown under the card
_CACHE_SIZE = 1024
_HIGHLIGHT_CACHE_SIZE = 64  # highlighted files (each at most a few MB of HTML)


class PageError(Exception):
    """A page that cannot be shown: an HTML error page with ``status``, naming what was not found."""

    def __init__(self, status: int, title: str, message: str):
        super().__init__(message)
        self.status = status
        self.title = title
        self.message = message


def wants_html(accept: str | None) -> bool:
    """Whether an ``Accept`` header asks for HTML (browsers send ``text/html,...``).

    Args:
        accept: the header's value, or None.

    >>> wants_html("text/html,application/xhtml+xml,*/*;q=0.8"), wants_html("*/*"), wants_html(None)
    (True, False, False)
    """
    return bool(accept) and "text/html" in accept.lower()


def format_size(n: int) -> str:
    """A file size for people.

    Args:
        n: a number of bytes.

    >>> format_size(0), format_size(1023), format_size(1536), format_size(5 * 1024**2)
    ('0 B', '1023 B', '1.5 kB', '5.0 MB')
    """
    if n < 1024:
        return f"{n} B"
    for unit in ("kB", "MB", "GB", "TB"):
        n /= 1024
        if n < 1024 or unit == "TB":
            return f"{n:.1f} {unit}"
    raise AssertionError("unreachable")


# --- the pages --------------------------------------------------------------------------------


@dataclass
class _Card:
    """What a README gives the pages, cached by the README's content."""

    title: str | None
    html: str
    truncated: bool
    not_rendered: str | None = None  # why the card is shown as plain text (None: rendered)


class Pages:
    """The page routes.

    Args:
        store: the repos.
        access: who may see what (a private repo's page needs the token, as its API routes do).
        cards: the README metadata, shared with the API's repo info.
    """

    def __init__(self, store: HubStore, access: Access, cards: CardData):
        self.store = store
        self.access = access
        self.cards = cards
        self.env = jinja2.Environment(
            loader=jinja2.FileSystemLoader(HERE / "templates"),
            autoescape=True,
            undefined=jinja2.StrictUndefined,
            trim_blocks=True,
            lstrip_blocks=True,
        )
        self.env.filters["size"] = format_size
        self.env.filters["seg"] = lambda s: quote(str(s), safe="")  # one path segment (a branch may hold '/')
        self.env.filters["date"] = lambda d: str(d).replace("T", " ")[:16] + " UTC" if d else ""
        self.env.globals["static"] = STATIC_PREFIX
        self._cards: OrderedDict[tuple[str, str], _Card] = OrderedDict()  # (README sha256, commit) -> card
        self._highlights: OrderedDict[tuple[str, str], str] = OrderedDict()  # (blob sha256, file name) -> HTML
        self._guard = threading.Lock()
        self._assets = _static_files()
        self.renderer = CardRenderer()  # card Markdown: in worker processes, within a time budget
        self.episodes = EpisodeReader()  # the dataset viewer's reads, cached
        self.records = Records()  # reproduction attestations, cached
        self.suites = SuiteTables()  # a suite's task table from its manifest, cached

    # -- routing --

    def match(self, ctx: Ctx) -> Callable[[Ctx], Response] | None:
        """The handler of a page route, or None if ``ctx`` is not one (then the API routes it).

        Args:
            ctx: the request (GET or HEAD).

        Returns:
            The page's handler, or None.
        """
        segs = ctx.segs
        html = wants_html(ctx.request.headers.get("accept"))
        if segs == [""]:
            return self._home if html else None
        if segs == ["favicon.ico"]:
            return lambda c: self._static("favicon.ico")
        if len(segs) == 3 and segs[0] == "_hub" and segs[1] == "static":
            return lambda c: self._static(segs[2])
        if not segs or segs[0] == "api":
            return None
        repo_type, rest = "model", segs
        if rest[0] in PLURAL:
            repo_type, rest = PLURAL[rest[0]], rest[1:]
        if len(rest) < 2 or not rest[0] or not rest[1]:
            return None
        repo_id = f"{rest[0]}/{rest[1]}"
        if len(rest) == 2:
            return lambda c: self._repo_page(c, repo_type, repo_id, None, "")
        action, args = rest[2], rest[3:]
        if action == "tree" and args:
            return lambda c: self._repo_page(c, repo_type, repo_id, args[0], "/".join(args[1:]))
        if action == "blob" and len(args) >= 2:
            return lambda c: self._blob_page(c, repo_type, repo_id, args[0], "/".join(args[1:]))
        if action == "commits" and len(args) == 1:
            return lambda c: self._commits_page(c, repo_type, repo_id, args[0])
        if action == "episodes":
            return self._match_episodes(repo_type, repo_id, args)
        if action == "discussions" and html and len(args) <= 1:  # API clients keep the API's answer there
            if not args:
                return lambda c: self._discussions_page(c, repo_type, repo_id)
            return lambda c: self._discussion_page(c, repo_type, repo_id, _number(args[0], "pull request"))
        return None

    def _match_episodes(self, repo_type: str, repo_id: str, args: list[str]) -> Callable[[Ctx], Response] | None:
        """``episodes``, ``episodes/{i}``, ``episodes/{i}/data.json``, ``episodes/{i}/frames/{key}/{step}.png``."""
        if not args:
            return lambda c: self._episodes_page(c, repo_type, repo_id)
        if len(args) == 1:
            return lambda c: self._episode_page(c, repo_type, repo_id, _number(args[0], "episode"))
        if len(args) == 2 and args[1] == "data.json":
            return lambda c: self._episode_data(c, repo_type, repo_id, _number(args[0], "episode"))
        if len(args) == 4 and args[1] == "frames" and args[3].endswith(".png"):
            step = args[3][: -len(".png")]
            return lambda c: self._episode_frame(
                c, repo_type, repo_id, _number(args[0], "episode"), args[2], _number(step, "frame")
            )
        return None

    def handle(self, ctx: Ctx, handler: Callable[[Ctx], Response]) -> Response:
        """Run a page handler; an error becomes an HTML page (its status, what was not found).

        Args:
            ctx: the request.
            handler: what :meth:`match` returned.

        Returns:
            The page, or an HTML error page with the error's status.
        """
        try:
            return handler(ctx)
        except PageError as err:
            return self._error(ctx, err)
        except RepoNotFoundError:
            status = 401 if (self.access.token is not None and not ctx.authenticated) else 404
            path = "/" + "/".join(ctx.segs)
            hint = (
                " This server was started with a token: a private repo is shown only to requests that send it "
                "(Authorization: Bearer <token>)."
                if status == 401
                else ""
            )
            return self._error(ctx, PageError(status, "Repository not found", f"No repository at {path}.{hint}"))
        except RevisionNotFoundError as err:
            return self._error(ctx, PageError(404, "Revision not found", _revision_message(err)))
        except EntryNotFoundError as err:
            return self._error(ctx, PageError(404, "File not found", str(err)))
        except InvalidPathError as err:
            return self._error(ctx, PageError(400, "Invalid path", str(err)))
        except InvalidNameError as err:
            return self._error(ctx, PageError(400, "Invalid name", str(err)))
        except PullRequestNotFoundError:
            return self._error(ctx, PageError(404, "Pull request not found", f"No pull request at /{'/'.join(ctx.segs)}."))
        except DatasetUnreadable as err:
            return self._error(ctx, PageError(422, "Dataset not shown", f"The viewer cannot show this dataset: {err}"))
        except StoreError:
            logger.exception("Store error on page %s", ctx.request.url.path)
            return self._error(ctx, PageError(500, "Server error", "The page failed on the server (details in its log)."))

    def _render(self, template: str, status: int = 200, **context) -> Response:
        body = self.env.get_template(template).render(**context)
        return Response(body, status_code=status, media_type="text/html; charset=utf-8", headers=dict(_PAGE_HEADERS))

    def _error(self, ctx: Ctx, err: PageError) -> Response:
        return self._render("error.html", status=err.status, title=err.title, message=err.message)

    def _static(self, name: str) -> Response:
        found = self._assets.get(name)
        if found is None:
            raise PageError(404, "Not found", f"No static file {name!r} on this server.")
        data, media_type = found
        headers = {**_PAGE_HEADERS, "Cache-Control": "public, max-age=3600"}
        return Response(data, media_type=media_type, headers=headers)

    # -- repos --

    def _open(self, ctx: Ctx, repo_type: str, repo_id: str) -> Repo:
        return self.access.open(ctx, repo_type, repo_id)  # private repos: the token, as the API

    def _card(self, repo: Repo, commit: Commit, base: str) -> _Card | None:
        entry = commit.files.get("README.md")
        if entry is None:
            return None
        key = (entry.sha256, f"{base}@{commit.id}")  # relative links pin the commit: part of the key
        with self._guard:
            if key in self._cards:
                self._cards.move_to_end(key)
                return self._cards[key]
        with repo.open_blob(entry) as f:
            raw = f.read(MAX_CARD_BYTES + 1)
        text = raw[:MAX_CARD_BYTES].decode("utf-8", "replace")
        body = strip_front_matter(text)
        links = Links(base, commit.id, folders_of(commit.files))
        card = _Card(card_title(body), "", truncated=len(raw) > MAX_CARD_BYTES)
        try:
            card.html = self.renderer.render(body, links)
        except CardNotRendered as err:
            card.html, card.not_rendered = plain_card(body), str(err)
            logger.warning("Showing the card of %s at %s as plain text: %s", repo.repo_id, commit.id[:12], err)
            if not err.cacheable:  # another view may render it
                return card
        with self._guard:
            self._cards[key] = card
            while len(self._cards) > _CACHE_SIZE:
                self._cards.popitem(last=False)
        return card

    def _title(self, repo: Repo, commit: Commit) -> str | None:
        """The card's title line, without rendering the card (the home page lists many)."""
        entry = commit.files.get("README.md")
        if entry is None:
            return None
        key = (entry.sha256, "")
        with self._guard:
            if key in self._cards:
                return self._cards[key].title
        with repo.open_blob(entry) as f:
            head = f.read(64 * 1024 + 4096).decode("utf-8", "replace")
        card = _Card(card_title(strip_front_matter(head)), "", False)
        with self._guard:
            self._cards[key] = card
            while len(self._cards) > _CACHE_SIZE:
                self._cards.popitem(last=False)
        return card.title

    def _home(self, ctx: Ctx) -> Response:
        query = (ctx.query("q") or "").strip()
        tag = (ctx.query("tag") or "").strip()
        needle = query.lower()
        repos = []
        for repo_type in ("model", "dataset", "space"):
            for meta in self.store.list_repos(repo_type):
                if meta.private and not ctx.authenticated:
                    continue
                try:
                    repo = self.store.open(repo_type, meta.repo_id)
                    head = repo.head()
                    card = self.cards.get(repo, head)
                    tags = card_tags(card)
                    if tag and tag not in tags:
                        continue
                    if needle and needle not in meta.repo_id.lower() and not any(needle in t.lower() for t in tags):
                        continue
                    thumb = _thumbnail(head)
                    base = "/" + URL_PREFIX[repo_type] + meta.repo_id
                    repos.append(
                        {
                            "id": meta.repo_id,
                            "type": repo_type,
                            "url": base,
                            "private": meta.private,
                            "title": self._title(repo, head),
                            "tags": tags,
                            "commit": head,
                            "thumbnail": f"{base}/resolve/{head.id}/{quote(thumb)}" if thumb else None,
                        }
                    )
                except StoreError:
                    continue
                except Exception:  # one broken repo must not break the page
                    logger.exception("Leaving %s %s out of the home page", repo_type, meta.repo_id)
        repos.sort(key=lambda r: r["commit"].date, reverse=True)
        return self._render("home.html", repos=repos, query=query, tag=tag)

    def _context(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str | None, path: str = "") -> dict:
        """What every page of a repo shows: the repo, the revision and its refs, the path and its crumbs."""
        repo = self._open(ctx, repo_type, repo_id)
        rev = revision or DEFAULT_BRANCH
        commit = repo.resolve(rev)
        refs = repo.refs()
        base = "/" + URL_PREFIX[repo_type] + repo.repo_id
        return {
            "repo": repo,
            "repo_id": repo.repo_id,
            "repo_type": repo_type,
            "base": base,
            "rev": rev,
            "rev_url": quote(rev, safe=""),
            "commit": commit,
            "branches": sorted(refs.branches.items()),
            "tags": sorted(refs.tags.items()),
            "private": repo.meta.private,
            "path": path,
            "crumbs": _crumbs(path),
            "has_dataset": any(p + INFO in commit.files for p in PREFIXES.get(repo_type, ())),
            "open_prs": sum(1 for pr in refs.pulls.values() if pr.status == "open"),
        }

    def _repo_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str | None, path: str) -> Response:
        path = path.strip("/")
        if path:
            validate_path(path)
        c = self._context(ctx, repo_type, repo_id, revision, path)
        repo, commit = c["repo"], c["commit"]
        folders = folders_of(commit.files)
        if path and path not in folders:
            what = "a file, not a folder" if path in commit.files else "not in this revision"
            raise PageError(404, "Folder not found", f"{path} is {what} ({repo.repo_id} at {c['rev']}).")
        prefix = f"{path}/" if path else ""
        entries = []
        for p in sorted(folders | set(commit.files)):
            if not p.startswith(prefix) or "/" in p[len(prefix) :] or p == path:
                continue
            entry = commit.files.get(p)
            if entry is None:
                count = sum(1 for f in commit.files if f.startswith(p + "/"))
                entries.append({"name": p[len(prefix) :], "path": p, "folder": True, "count": count})
            else:
                entries.append({"name": p[len(prefix) :], "path": p, "folder": False, "size": entry.size, "lfs": entry.lfs})
        entries.sort(key=lambda e: (not e["folder"], e["name"].lower()))
        card = self._card(repo, commit, c["base"]) if not path else None
        data = self.cards.get(repo, commit) if not path else None
        recent = []
        for i, old in enumerate(repo.history(commit)):
            if i >= RECENT_COMMITS:
                break
            recent.append(old)
        shown = [e for p, e in commit.files.items() if p.startswith(prefix)]  # the folder's files (all of them at the root)
        attested = self.records.attested(repo, commit, c["base"]) if not path else []
        return self._render(
            "repo.html",
            **c,
            entries=entries,
            card=card,
            card_tags=card_tags(data),
            card_fields=card_fields(data),
            results=eval_results(data),
            load_line=load_line(repo.repo_id, repo_type, commit),
            recent=recent,
            reproductions=matrix(attested),
            suite_tasks=self.suites.get(repo, commit) if not path and repo_type == "model" else [],
            merge_rights=self._merge_rights(repo),
            rollout_video=_ROLLOUT_VIDEO if not path and _ROLLOUT_VIDEO in commit.files else None,
            shown_files=len(shown),
            shown_size=sum(e.size for e in shown),
        )

    def _blob_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
        validate_path(path)  # before anything: a traversal attempt is a 400, as in the API
        c = self._context(ctx, repo_type, repo_id, revision, path)
        repo, commit = c["repo"], c["commit"]
        entry = commit.files.get(path)
        if entry is None:
            if path in folders_of(commit.files):
                raise PageError(404, "File not found", f"{path} is a folder ({repo.repo_id} at {c['rev']}).")
            raise PageError(404, "File not found", f"No file {path} in {repo.repo_id} at {c['rev']}.")
        ext = posixpath.splitext(path)[1].lower()
        raw_url = f"{c['base']}/resolve/{commit.id}/{quote(path)}"
        kind, code = "download", None
        if ext in _IMAGE_EXT:
            kind = "image"
        elif ext in _VIDEO_EXT:
            kind = "video"
        elif entry.size <= MAX_TEXT_BYTES:
            with repo.open_blob(entry) as f:
                data = f.read()
            text = as_text(data)
            if text is not None:
                kind, code = "text", self._highlighted(entry.sha256, path, text)
        return self._render(
            "blob.html",
            **c,
            entry=entry,
            kind=kind,
            code=code,
            raw_url=raw_url,
            lfs=entry.lfs,
            media_type=mimetypes.guess_type(path)[0] or "application/octet-stream",
        )

    def _highlighted(self, sha256: str, path: str, text: str) -> str:
        key = (sha256, "highlight:" + path.rsplit("/", 1)[-1])  # the lexer follows the file name
        with self._guard:
            if key in self._highlights:
                self._highlights.move_to_end(key)
                return self._highlights[key]
        code = highlight_file(path, text)
        with self._guard:
            self._highlights[key] = code
            while len(self._highlights) > _HIGHLIGHT_CACHE_SIZE:
                self._highlights.popitem(last=False)
        return code

    def _commits_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
        c = self._context(ctx, repo_type, repo_id, revision)
        try:
            page = max(0, int(ctx.query("p") or 0))
        except ValueError:
            raise PageError(400, "Invalid page", f"Invalid page number {ctx.query('p')!r}: expected 0, 1, 2...") from None
        commits, more = [], False
        for i, old in enumerate(c["repo"].history(c["commit"])):
            if i >= (page + 1) * COMMITS_PAGE:
                more = True
                break
            if i >= page * COMMITS_PAGE:
                commits.append(old)
        return self._render("commits.html", **c, commits=commits, page=page, more=more, next_query=urlencode({"p": page + 1}))

    # -- the dataset viewer --

    def _dataset(self, ctx: Ctx, repo_type: str, repo_id: str) -> tuple[dict, Any]:
        """The repo's page context at ``?rev=`` (default main) and the dataset it holds (404 if none)."""
        c = self._context(ctx, repo_type, repo_id, ctx.query("rev") or None)
        ds = find_dataset(c["repo"], c["commit"])
        if ds is None:
            where = " or ".join(f"{p or 'the root'}" for p in PREFIXES.get(repo_type, ())) or "this kind of repo"
            raise PageError(
                404,
                "No dataset",
                f"{c['repo_id']} at {c['rev']} holds no LeRobot dataset (no {INFO} in {where}).",
            )
        return c, ds

    def _episodes_page(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        c, ds = self._dataset(ctx, repo_type, repo_id)
        index = self.episodes.index(ds)
        page = _number(ctx.query("p") or "0", "page", minimum=0)
        rows = index.episodes[page * EPISODES_PAGE : (page + 1) * EPISODES_PAGE]
        if page and not rows:
            raise PageError(404, "No such page", f"Page {page} is past the last episode ({len(index)} episodes).")
        return self._render(
            "episodes.html",
            **c,
            ds=ds,
            rows=rows,
            total=len(index),
            page=page,
            pages=(len(index) + EPISODES_PAGE - 1) // EPISODES_PAGE,
            frames=sum(e.length for e in index.episodes),
        )

    def _episode(self, ctx: Ctx, repo_type: str, repo_id: str, i: int) -> tuple[dict, Any, Any, Any]:
        c, ds = self._dataset(ctx, repo_type, repo_id)
        index = self.episodes.index(ds)
        episode = index.get(i)
        if episode is None:
            raise PageError(404, "Episode not found", f"No episode {i} in {c['repo_id']} at {c['rev']} ({len(index)} episodes).")
        return c, ds, index, episode

    def _episode_page(self, ctx: Ctx, repo_type: str, repo_id: str, i: int) -> Response:
        c, ds, index, episode = self._episode(ctx, repo_type, repo_id, i)
        sha = c["commit"].id
        videos = []
        for key, (chunk, file, start, stop) in sorted(episode.videos.items()):
            path = ds.path("video_path", video_key=key, chunk_index=chunk, file_index=file)
            if ds.file(path) is not None:
                videos.append(
                    {"key": key, "url": f"{c['base']}/resolve/{sha}/{quote(ds.prefix + path)}", "from": start, "to": stop}
                )
        position = index.episodes.index(episode)
        neighbours = index.episodes[max(position - 1, 0) : position + 2]
        return self._render(
            "episode.html",
            **c,
            ds=ds,
            episode=episode,
            total=len(index),
            previous=neighbours[0] if neighbours[0] is not episode else None,
            next=neighbours[-1] if neighbours[-1] is not episode else None,
            videos=videos,
            images=ds.image_keys,
            series=[(k, ds.names(k)) for k in ds.series_keys],
            data_url=f"{c['base']}/episodes/{episode.index}/data.json?{urlencode({'rev': sha})}",
            frames_url=f"{c['base']}/episodes/{episode.index}/frames",
            extra_scripts=["viewer.js"],
        )

    def _episode_data(self, ctx: Ctx, repo_type: str, repo_id: str, i: int) -> Response:
        c, ds, _, episode = self._episode(ctx, repo_type, repo_id, i)
        data = {"episode": episode.index, "length": episode.length, "fps": ds.fps, **self.episodes.series(ds, episode)}
        headers = {**_PAGE_HEADERS, **_immutable(ctx, c["commit"].id)}
        return Response(json.dumps(data, allow_nan=False), media_type="application/json", headers=headers)

    def _episode_frame(self, ctx: Ctx, repo_type: str, repo_id: str, i: int, key: str, step: int) -> Response:
        c, ds, _, episode = self._episode(ctx, repo_type, repo_id, i)
        png = self.episodes.frame(ds, episode, key, step)
        headers = {**_PAGE_HEADERS, **_immutable(ctx, c["commit"].id)}
        return Response(png, media_type="image/png", headers=headers)

    # -- pull requests --

    def _merge_rights(self, repo: Repo) -> str:
        """Who may merge the repo's pull requests, in words."""
        owner = repo.repo_id.split("/")[0]
        if owner.lower() == self.access.user.lower():
            return f"the account {self.access.user!r}"
        return f"the account {owner!r} (the repo's namespace) or the server's own account {self.access.user!r}"

    def _discussions_page(self, ctx: Ctx, repo_type: str, repo_id: str) -> Response:
        c = self._context(ctx, repo_type, repo_id, None)
        repo = c["repo"]
        prs = repo.pull_requests()
        rows = []
        for pr in prs:
            base, head = repo.load_commit(pr.base), repo.load_commit(pr.head)
            changed = [p for p in set(base.files) | set(head.files) if base.files.get(p) != head.files.get(p)]
            rows.append({"pr": pr, "files": len(changed), "records": sum(1 for p in changed if is_record(p) and p in head.files)})
        return self._render("discussions.html", **c, rows=rows)

    def _discussion_page(self, ctx: Ctx, repo_type: str, repo_id: str, num: int) -> Response:
        c = self._context(ctx, repo_type, repo_id, None)
        repo = c["repo"]
        pr = repo.pull_request(num)
        base, head = repo.load_commit(pr.base), repo.load_commit(pr.head)
        files = changes(repo, base, head)
        records = []
        for f in files:
            if f.new is not None and is_record(f.path):
                record = self.records.read(repo, f.path, f.new)
                records.append({"record": record, "signed": f.path + ".sig" in head.files})
        kind = "" if repo_type == "model" else f", repo_type={repo_type!r}"
        return self._render(
            "discussion.html",
            **c,
            pr=pr,
            head=head,
            files=files,
            records=records,
            merge_call=f"HfApi().merge_pull_request({repo.repo_id!r}, {pr.num}{kind})",
            merge_rights=self._merge_rights(repo),
            events=[_event_row(e) for e in pr.events],
        )


# --- helpers ----------------------------------------------------------------------------------


def load_line(repo_id: str, repo_type: str, commit: Commit) -> str:
    """The line that loads this repo pinned to this commit: ``load_env`` for an env repo (one with a
    ``hub_env.json``), else ``snapshot_download``; the same text push_env prints.

    Args:
        repo_id: ``namespace/name``.
        repo_type: ``model``, ``dataset`` or ``space``.
        commit: the commit to pin.
    """
    if repo_type == "model" and ENV_MANIFEST in commit.files:
        return f'load_env("{repo_id}@{commit.id}", trust_remote_code=True)'
    kind = "" if repo_type == "model" else f', repo_type="{repo_type}"'
    return f'snapshot_download("{repo_id}"{kind}, revision="{commit.id}")'


def _number(text: str, what: str, minimum: int = 0) -> int:
    """A non-negative number from a path segment or query value; 400 if it is not one."""
    if not text.isdigit() or len(text) > 9 or int(text) < minimum:
        raise PageError(400, f"Invalid {what} number", f"Invalid {what} number {text[:20]!r}: expected 0, 1, 2...")
    return int(text)


def _immutable(ctx: Ctx, sha: str) -> dict:
    """Cache headers of an answer for a pinned commit (``?rev=<sha>``): it never changes."""
    return {"Cache-Control": "public, max-age=86400, immutable"} if ctx.query("rev") == sha else {}


def _event_row(event: dict) -> dict:
    """A pull request event as the page lists it: who, when, what."""
    data = event.get("data") if isinstance(event.get("data"), dict) else {}
    author = event.get("author", {}).get("name") if isinstance(event.get("author"), dict) else None
    kind = event.get("type")
    if kind == "comment":
        latest = data.get("latest") if isinstance(data.get("latest"), dict) else {}
        text = str(latest.get("raw") or "")
    elif kind == "commit":
        text = f"pushed {str(data.get('oid', ''))[:12]}: {data.get('subject', '')}"
    elif kind == "status-change":
        text = f"changed the status to {data.get('status')}"
    else:
        text = str(kind)
    return {"type": kind, "author": author, "date": event.get("createdAt"), "text": text[:20_000]}


def _thumbnail(commit: Commit) -> str | None:
    if _THUMBNAIL in commit.files:
        return _THUMBNAIL
    gifs = sorted(p for p in commit.files if p.lower().endswith(".gif"))
    return gifs[0] if gifs else None


def _crumbs(path: str) -> list[tuple[str, str]]:
    parts = path.split("/") if path else []
    return [(part, "/".join(parts[: i + 1])) for i, part in enumerate(parts)]


def _revision_message(err: RevisionNotFoundError) -> str:
    text = str(err)
    prefix = "Invalid rev id: "
    if text.startswith(prefix):
        return f"No branch, tag or commit named {text[len(prefix) :]!r} in this repository."
    return text


def _static_files() -> dict[str, tuple[bytes, str]]:
    static = HERE / "static"
    css = (static / "hub.css").read_text() + "\n/* Pygments */\n" + HtmlFormatter().get_style_defs(".highlight")
    return {
        "hub.css": (css.encode(), "text/css; charset=utf-8"),
        "hub.js": ((static / "hub.js").read_bytes(), "text/javascript; charset=utf-8"),
        "viewer.js": ((static / "viewer.js").read_bytes(), "text/javascript; charset=utf-8"),
        "favicon.svg": (FAVICON_SVG.encode(), "image/svg+xml"),
        "favicon.ico": (_favicon_ico(), "image/x-icon"),
    }


#: The pages' icon: a rounded square in the pages' accent colour with a white "h".
FAVICON_SVG = (
    '<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 32 32"><rect width="32" height="32" rx="7" fill="#0b5fcc"/>'
    '<path d="M10 7v18M10 16c2-3 9-3 10 1v8" stroke="#fff" stroke-width="4" fill="none" stroke-linecap="round"/></svg>'
)


def _favicon_ico(size: int = 32) -> bytes:
    """``/favicon.ico`` (what a browser asks for on a page without an icon link, e.g. a file opened raw): the
    accent-coloured square of :data:`FAVICON_SVG`, as an ICO holding one PNG, drawn here (no image library)."""
    color, white = (0x0B, 0x5F, 0xCC, 255), (255, 255, 255, 255)
    rows = []
    for y in range(size):
        row = bytearray([0])  # PNG filter: none
        for x in range(size):
            stem = 9 <= x <= 12 and 6 <= y <= 25
            leg = 18 <= x <= 21 and 15 <= y <= 25
            arch = 11 <= x <= 21 and 13 <= y <= 16
            row += bytes(white if (stem or leg or arch) else color)
        rows.append(bytes(row))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", size, size, 8, 6, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(b"".join(rows), 9))
        + chunk(b"IEND", b"")
    )
    header = struct.pack("<HHH", 0, 1, 1) + struct.pack("<BBBBHHII", size, size, 0, 0, 1, 32, len(png), 6 + 16)
    return header + png


class ResolveSandbox:
    """ASGI middleware: ``/resolve/`` answers carry :data:`RESOLVE_CSP` and ``nosniff``, so a repo's
    HTML or SVG opened in a browser runs no script on this server's origin. Bodies are untouched."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or b"/resolve/" not in (scope.get("raw_path") or scope["path"].encode()):
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers.append((b"content-security-policy", RESOLVE_CSP.encode()))
                headers.append((b"x-content-type-options", b"nosniff"))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)
