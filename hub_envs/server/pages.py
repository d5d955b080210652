"""The web pages of the loopback Hub: what a person sees who points a browser at ``hub-envs serve``.

Server-rendered HTML (Jinja templates under ``templates/``, one stylesheet and one small script
under ``static/``; no build step, no framework):

* ``/`` (only when the request accepts ``text/html``: API clients still get the API's 404): every
  repo, newest commit first, with its card's title line, tags, last commit and rollout GIF; a
  search box (``?q=``: repo name or tag) and tag links (``?tag=``).
* ``/{user}/{repo}`` and ``/{user}/{repo}/tree/{rev}[/{folder}]``: the file list (sizes, LFS
  markers), the card rendered from its Markdown, its YAML metadata as tags and evaluation results,
  the load line pinned to the commit sha with a copy button, branches, tags, recent commits and
  the reproduction reports the revision holds (``reproductions/*.json``).
* ``/{user}/{repo}/blob/{rev}/{path}``: a text file (highlighted with Pygments), an image or video
  inline, or anything else as a download link.
* ``/{user}/{repo}/commits/{rev}``: the history, paged.

The same paths under ``/datasets/`` and ``/spaces/`` show those repo types.

Safe by construction:

* Card Markdown is rendered by markdown-it-py with raw HTML off (a ``<script>`` in a card is shown
  as text) and its link validation (no ``javascript:`` links); every page carries a
  Content-Security-Policy that allows scripts, styles, images and media from this server only, and no
  inline script or style at all. ``/resolve/`` answers (files a repo author wrote) get a ``sandbox``
  policy, so an HTML or SVG file opened from a repo runs nothing either.
* Paths go through :func:`~hub_envs.server.storage.validate_path`, the API's traversal check: 400.
* Private repos need the token, as the API does (``Authorization: Bearer``): without it they are
  left out of ``/`` and their pages answer 401, as the API's routes do.

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
import os
import posixpath
import re
import subprocess
import sys
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import quote, unquote, urlencode, urlsplit

import jinja2
from markdown_it import MarkdownIt
from markupsafe import escape
from pygments import highlight as pygments_highlight
from pygments.formatters import HtmlFormatter
from pygments.lexers import get_lexer_by_name, get_lexer_for_filename
from pygments.util import ClassNotFound
from starlette.responses import Response

from hub_envs.server.storage import (
    DEFAULT_BRANCH,
    Commit,
    EntryNotFoundError,
    InvalidNameError,
    InvalidPathError,
    Repo,
    RepoNotFoundError,
    RevisionNotFoundError,
    StoreError,
    folders_of,
    validate_path,
)

if TYPE_CHECKING:  # app imports this module; this module needs app's types for hints only
    from hub_envs.server.app import Ctx, HubApp

logger = logging.getLogger("hub_envs.server")

HERE = Path(__file__).resolve().parent
STATIC_PREFIX = "/_hub/static/"  # "_hub" cannot be a namespace: repo ids start with a letter or digit
_PLURAL = {"models": "model", "datasets": "dataset", "spaces": "space"}
_URL_PREFIX = {"model": "", "dataset": "datasets/", "space": "spaces/"}

#: Every page: scripts, styles, images and media from this server only; no inline script or style,
#: no plugins, no frames, forms post back here only.
PAGE_CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; media-src 'self'; "
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
MAX_HIGHLIGHT_BYTES = 256 * 1024  # highlighted up to this size; plain text above
RECENT_COMMITS = 8
COMMITS_PAGE = 50
_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".gif", ".webp", ".bmp", ".svg", ".ico"}
_VIDEO_EXT = {".mp4", ".webm", ".ogv"}
_THUMBNAIL = "media/rollout.gif"  # what push_env renders for the card
_ROLLOUT_VIDEO = "media/rollout.mp4"  # beside it when the dataset stores video: shown under the card
_CACHE_SIZE = 1024
_HIGHLIGHT_CACHE_SIZE = 64  # highlighted files (each at most a few MB of HTML)
#: A card's Markdown is rendered in a worker process within this many seconds (env
#: ``HUB_ENVS_SERVER_CARD_RENDER_SECONDS``); past it, the page shows the card as plain text, with a note.
CARD_RENDER_SECONDS = 3.0
_RENDER_WORKERS = 2  # cards rendered at once; a page waits at most the budget for one of them
_RENDER_START_SECONDS = 60.0  # a worker's start (its imports) is not part of a card's budget


class PageError(Exception):
    """A page that cannot be shown: an HTML error page with ``status``, naming what was not found."""

    def __init__(self, status: int, title: str, message: str):
        super().__init__(message)
        self.status = status
        self.title = title
        self.message = message


def wants_html(accept: str | None) -> bool:
    """Whether an ``Accept`` header asks for HTML (browsers send ``text/html,...``).

    >>> wants_html("text/html,application/xhtml+xml,*/*;q=0.8"), wants_html("*/*"), wants_html(None)
    (True, False, False)
    """
    return bool(accept) and "text/html" in accept.lower()


def format_size(n: int) -> str:
    """A file size for people.

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


def _highlight_code(code: str, lang: str, _attrs: str) -> str:
    """markdown-it's fence highlighter: Pygments for a known language, else markdown-it's escaping."""
    if not lang or len(code) > MAX_HIGHLIGHT_BYTES:
        return ""
    try:
        lexer = get_lexer_by_name(lang.split()[0].lower())
    except ClassNotFound:
        return ""
    # starts with "<pre": markdown-it then uses it as the whole block (no second <pre><code> around it)
    return f'<pre class="highlight"><code>{pygments_highlight(code, lexer, _FENCE_FORMATTER)}</code></pre>'


_FENCE_FORMATTER = HtmlFormatter(nowrap=True)
_FILE_FORMATTER = HtmlFormatter(cssclass="highlight", wrapcode=True, linenos="table", lineanchors="L", anchorlinenos=True)


@lru_cache(maxsize=1)
def _markdown() -> MarkdownIt:
    # CommonMark with raw HTML off (a card's <script> or <img onerror> becomes text), plus tables
    # and strikethrough as on the Hub. Links keep markdown-it's validation (no javascript:/vbscript:/
    # file: links; data: only for images, which the page's CSP then blocks).
    return MarkdownIt("commonmark", {"html": False, "highlight": _highlight_code}).enable(["table", "strikethrough"])


_ALIGN_RE = re.compile(r"^text-align:(left|right|center)$")
_SCHEME_RE = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


@dataclass
class _Links:
    """How a card's relative links and images resolve: into the repo at the pinned commit."""

    base: str  # /{prefix}{repo_id}
    sha: str
    folders: set[str]  # the commit's folders: a link to one goes to its tree page

    def target(self, url: str) -> str | None:
        """The repo path a relative ``url`` names (``./media/a.gif#x`` -> ``media/a.gif``), or None."""
        if not url or url.startswith(("#", "/", "?")) or _SCHEME_RE.match(url):
            return None
        path = unquote(urlsplit(url).path)
        norm = posixpath.normpath(path)
        if norm in ("", ".") or norm.startswith(".."):
            return None
        try:
            return validate_path(norm)
        except InvalidPathError:
            return None

    def image(self, url: str) -> str:
        path = self.target(url)
        if path is None:
            return url
        return f"{self.base}/resolve/{self.sha}/{quote(path)}"

    def link(self, url: str) -> str:
        path = self.target(url)
        if path is None:
            return url
        fragment = urlsplit(url).fragment
        kind = "tree" if path in self.folders else "blob"
        return f"{self.base}/{kind}/{self.sha}/{quote(path)}" + (f"#{fragment}" if fragment else "")


def render_markdown(text: str, links: _Links | None = None) -> str:
    """Card Markdown as HTML: raw HTML escaped, relative images served from the repo at the pinned
    commit, relative links to the file pages, table alignment as classes (the page's CSP allows no
    inline style).

    >>> render_markdown("Hi <script>alert(1)</script> [x](javascript:alert(1))")
    '<p>Hi &lt;script&gt;alert(1)&lt;/script&gt; [x](javascript:alert(1))</p>\\n'
    >>> links = _Links("/alice/env", "a" * 40, folders=set())
    >>> render_markdown("![roll](media/a.gif)", links)
    '<p><img src="/alice/env/resolve/aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa/media/a.gif" alt="roll" /></p>\\n'
    """
    md = _markdown()
    tokens = md.parse(text)
    for token in tokens:
        style = token.attrGet("style")
        if style is not None:
            match = _ALIGN_RE.match(str(style))
            token.attrs.pop("style", None)
            if match:
                token.attrSet("class", f"align-{match.group(1)}")
        if token.type == "table_open":
            token.attrSet("class", "card-table")
        for child in token.children or ():
            if links is None:
                continue
            if child.type == "image":
                child.attrSet("src", links.image(str(child.attrGet("src") or "")))
            elif child.type == "link_open":
                child.attrSet("href", links.link(str(child.attrGet("href") or "")))
    return md.renderer.render(tokens, md.options, {})


# --- rendering cards in worker processes -------------------------------------------------------


class CardNotRendered(Exception):
    """A card could not be rendered: over the time budget (``cacheable``: it would be again), or no renderer."""

    def __init__(self, message: str, cacheable: bool):
        super().__init__(message)
        self.cacheable = cacheable


class _RenderWorker:
    """One renderer process (:func:`render_worker`), spoken to over two pipes: a request is a JSON message
    ``{"text", "base", "sha", "folders"}``, an answer ``{"html"}`` or ``{"error"}`` (length-prefixed bytes of
    :class:`multiprocessing.connection.Connection`; JSON both ways, so nothing is unpickled)."""

    def __init__(self):
        from multiprocessing.connection import Connection

        child_reads, parent_writes = os.pipe()
        parent_reads, child_writes = os.pipe()
        package_root = str(Path(__file__).resolve().parents[2])  # hub_envs' parent folder: importable in the child
        env = {**os.environ, "PYTHONSAFEPATH": "1"}  # not the server's working folder on sys.path
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [package_root, env.get("PYTHONPATH")]))
        code = f"from hub_envs.server.pages import render_worker; render_worker({child_reads}, {child_writes})"
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-c", code],
                stdin=subprocess.DEVNULL,
                pass_fds=(child_reads, child_writes),
                env=env,
                start_new_session=True,  # Ctrl-C on the server's terminal is the server's: it never reaches a renderer
            )
        except OSError:
            os.close(parent_writes)
            os.close(parent_reads)
            raise
        finally:
            os.close(child_reads)
            os.close(child_writes)
        self.send = Connection(parent_writes, readable=False)
        self.receive = Connection(parent_reads, writable=False)
        try:
            if not self.receive.poll(_RENDER_START_SECONDS) or self.receive.recv_bytes() != b"ready":
                raise OSError(f"the card renderer did not start within {_RENDER_START_SECONDS:g} s")
        except (EOFError, OSError):
            self.kill()
            raise

    def kill(self) -> None:
        self.process.kill()
        self.process.wait()
        self.send.close()
        self.receive.close()


class CardRenderer:
    """Renders card Markdown in worker processes, each card within a time budget.

    markdown-it is fast on cards people write, but some Markdown within the 512 KiB a page renders takes it
    seconds to tens of seconds (thousands of nested ``![`` or ``[``). Rendered in the server's own process it
    would share the GIL and the thread pool with every API request; here a worker process renders it, a page
    waits at most ``budget`` seconds for a free worker and ``budget`` more for the HTML, and a worker past the
    budget is killed (a new one starts for the next card). Then :class:`CardNotRendered` says so.

    Args:
        budget: seconds a card may take to render (default :data:`CARD_RENDER_SECONDS`, or env
            ``HUB_ENVS_SERVER_CARD_RENDER_SECONDS``).
        workers: renderer processes at most (started when first needed; each is reused).
    """

    def __init__(self, budget: float | None = None, workers: int = _RENDER_WORKERS):
        if budget is None:
            raw = os.environ.get("HUB_ENVS_SERVER_CARD_RENDER_SECONDS", "").strip()
            try:
                budget = float(raw) if raw else CARD_RENDER_SECONDS
            except ValueError:
                raise ValueError(f"HUB_ENVS_SERVER_CARD_RENDER_SECONDS={raw!r}: expected a number of seconds.") from None
        if not 0 < budget < float("inf"):
            raise ValueError(f"The card render budget must be a positive number of seconds, got {budget}.")
        self.budget = budget
        self._slots = threading.BoundedSemaphore(workers)
        self._idle: list[_RenderWorker] = []
        self._guard = threading.Lock()

    def render(self, text: str, links: _Links) -> str:
        """The HTML of card Markdown ``text`` (as :func:`render_markdown` makes it).

        Raises:
            CardNotRendered: over the budget (``cacheable``), every worker busy past the budget, or no
                worker could start or answer (both not ``cacheable``: another view may render it).
        """
        if not self._slots.acquire(timeout=self.budget):
            raise CardNotRendered(f"every card renderer stayed busy for {self.budget:g} s", cacheable=False)
        worker = None
        try:
            with self._guard:
                worker = self._idle.pop() if self._idle else None
            if worker is None:
                worker = _RenderWorker()  # its start is not part of the budget
            request = {"text": text, "base": links.base, "sha": links.sha, "folders": sorted(links.folders)}
            worker.send.send_bytes(json.dumps(request).encode())
            if not worker.receive.poll(self.budget):
                worker.kill()
                worker = None
                raise CardNotRendered(f"it takes longer than {self.budget:g} s to render", cacheable=True)
            answer = json.loads(worker.receive.recv_bytes())
            if "html" not in answer:
                raise CardNotRendered(f"the renderer failed: {str(answer.get('error'))[:300]}", cacheable=True)
            return answer["html"]
        except (EOFError, OSError, ValueError) as err:  # the worker died, or never started
            logger.error("Card renderer failed: %s: %s", type(err).__name__, err)
            if worker is not None:
                worker.kill()
                worker = None
            raise CardNotRendered("the renderer failed (details in the server's log)", cacheable=False) from None
        finally:
            if worker is not None:
                with self._guard:
                    self._idle.append(worker)
            self._slots.release()

    def close(self) -> None:
        """Stop the idle workers (a busy one is stopped by its render)."""
        with self._guard:
            idle, self._idle = self._idle, []
        for worker in idle:
            worker.kill()


def render_worker(read_fd: int, write_fd: int) -> None:
    """The loop of a renderer process (see :class:`CardRenderer`): until the server closes its pipe, render
    each request and answer it."""
    from multiprocessing.connection import Connection

    requests, answers = Connection(read_fd, writable=False), Connection(write_fd, readable=False)
    render_markdown("warm up")  # imports and builds the parser before the first card's budget starts
    answers.send_bytes(b"ready")
    while True:
        try:
            request = json.loads(requests.recv_bytes())
        except (EOFError, OSError):
            return  # the server is gone (or stopped this worker)
        try:
            links = _Links(request["base"], request["sha"], set(request["folders"]))
            answer = {"html": render_markdown(request["text"], links)}
        except Exception as err:  # a bug in rendering: the page shows the card as text and the log says why
            answer = {"error": f"{type(err).__name__}: {str(err)[:300]}"}
        answers.send_bytes(json.dumps(answer).encode())


def plain_card(text: str) -> str:
    """Card Markdown shown as it is written, escaped: what a page shows when the card cannot be rendered.

    >>> plain_card("# Hi <script>")
    '<pre class="card-plain"># Hi &lt;script&gt;</pre>'
    """
    return f'<pre class="card-plain">{escape(text)}</pre>'


# --- card metadata ----------------------------------------------------------------------------


def card_title(body: str) -> str | None:
    """The card's title line: its first ``# heading`` (front matter already cut off).

    >>> card_title("Intro\\n\\n# tiny-env — a hub-envs environment\\n## Load it")
    'tiny-env — a hub-envs environment'
    """
    for line in body.splitlines()[:200]:
        if line.startswith("# "):
            return line[2:].strip().strip("#").strip() or None
    return None


def eval_results(card: dict | None) -> list[dict]:
    """The evaluation results of a card's ``model-index`` metadata, one row per metric.

    >>> eval_results({"model-index": [{"name": "a/b", "results": [{"task": {"type": "rl"},
    ...     "dataset": {"name": "tiny"}, "metrics": [{"type": "mean_return", "value": -8.2, "name": "mean_return (random policy)"}]}]}]})
    [{'model': 'a/b', 'task': 'rl', 'dataset': 'tiny', 'metric': 'mean_return (random policy)', 'value': '-8.2', 'verified': False}]
    """
    rows: list[dict] = []
    index = card.get("model-index") if isinstance(card, dict) else None
    if not isinstance(index, list):
        return rows
    for model in index[:20]:
        if not isinstance(model, dict):
            continue
        for result in (model.get("results") or [])[:50] if isinstance(model.get("results"), list) else []:
            if not isinstance(result, dict):
                continue
            task = result.get("task") if isinstance(result.get("task"), dict) else {}
            dataset = result.get("dataset") if isinstance(result.get("dataset"), dict) else {}
            metrics = result.get("metrics") if isinstance(result.get("metrics"), list) else []
            for metric in metrics[:50]:
                if not isinstance(metric, dict):
                    continue
                value = metric.get("value")
                rows.append(
                    {
                        "model": str(model.get("name") or ""),
                        "task": str(task.get("name") or task.get("type") or ""),
                        "dataset": str(dataset.get("name") or dataset.get("type") or ""),
                        "metric": str(metric.get("name") or metric.get("type") or ""),
                        "value": f"{value:.4g}" if isinstance(value, float) else str(value),
                        "verified": metric.get("verified") is True,
                    }
                )
    return rows


def card_fields(card: dict | None) -> list[tuple[str, str]]:
    """The card metadata's plain fields (``library_name``, ``license``...) as ``(key, value)`` rows;
    tags and model-index are shown on their own."""
    if not isinstance(card, dict):
        return []
    out = []
    for key, value in card.items():
        if key in ("tags", "model-index") or isinstance(value, (dict, list)) or value is None:
            continue
        out.append((str(key), str(value)[:200]))
    return out[:20]


def card_tags(card: dict | None) -> list[str]:
    tags = card.get("tags") if isinstance(card, dict) else None
    return [str(t) for t in tags[:50]] if isinstance(tags, list) else []


# --- the pages --------------------------------------------------------------------------------


@dataclass
class _Card:
    """What a README gives the pages, cached by the README's content."""

    title: str | None
    html: str
    truncated: bool
    not_rendered: str | None = None  # why the card is shown as plain text (None: rendered)


class Pages:
    """The page routes, bound to a :class:`~hub_envs.server.app.HubApp` (its store and its auth)."""

    def __init__(self, hub: HubApp):
        self.hub = hub
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
        self._static = _static_files()
        self.renderer = CardRenderer()  # card Markdown: in worker processes, within a time budget

    # -- routing --

    def match(self, ctx: Ctx) -> Callable[[Ctx], Response] | None:
        """The handler of a page route, or None if ``ctx`` is not one (then the API routes it)."""
        segs = ctx.segs
        if segs == [""]:
            return self.home if wants_html(ctx.request.headers.get("accept")) else None
        if len(segs) == 3 and segs[0] == "_hub" and segs[1] == "static":
            return lambda c: self.static(segs[2])
        if not segs or segs[0] == "api":
            return None
        repo_type, rest = "model", segs
        if rest[0] in _PLURAL:
            repo_type, rest = _PLURAL[rest[0]], rest[1:]
        if len(rest) < 2 or not rest[0] or not rest[1]:
            return None
        repo_id = f"{rest[0]}/{rest[1]}"
        if len(rest) == 2:
            return lambda c: self.repo_page(c, repo_type, repo_id, None, "")
        action, args = rest[2], rest[3:]
        if action == "tree" and args:
            return lambda c: self.repo_page(c, repo_type, repo_id, args[0], "/".join(args[1:]))
        if action == "blob" and len(args) >= 2:
            return lambda c: self.blob_page(c, repo_type, repo_id, args[0], "/".join(args[1:]))
        if action == "commits" and len(args) == 1:
            return lambda c: self.commits_page(c, repo_type, repo_id, args[0])
        return None

    def handle(self, ctx: Ctx, handler: Callable[[Ctx], Response]) -> Response:
        """Run a page handler; an error becomes an HTML page (its status, what was not found)."""
        try:
            return handler(ctx)
        except PageError as err:
            return self._error(ctx, err)
        except RepoNotFoundError:
            status = 401 if (self.hub.token is not None and not ctx.authenticated) else 404
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
        except StoreError:
            logger.exception("Store error on page %s", ctx.request.url.path)
            return self._error(ctx, PageError(500, "Server error", "The page failed on the server (details in its log)."))

    def _render(self, template: str, status: int = 200, **context) -> Response:
        body = self.env.get_template(template).render(**context)
        return Response(body, status_code=status, media_type="text/html; charset=utf-8", headers=dict(_PAGE_HEADERS))

    def _error(self, ctx: Ctx, err: PageError) -> Response:
        return self._render("error.html", status=err.status, title=err.title, message=err.message)

    def static(self, name: str) -> Response:
        found = self._static.get(name)
        if found is None:
            raise PageError(404, "Not found", f"No static file {name!r} on this server.")
        data, media_type = found
        headers = {**_PAGE_HEADERS, "Cache-Control": "public, max-age=3600"}
        return Response(data, media_type=media_type, headers=headers)

    # -- repos --

    def _open(self, ctx: Ctx, repo_type: str, repo_id: str) -> Repo:
        return self.hub._open(ctx, repo_type, repo_id)  # private repos: the token, as the API

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
        links = _Links(base, commit.id, folders_of(commit.files))
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

    def home(self, ctx: Ctx) -> Response:
        query = (ctx.query("q") or "").strip()
        tag = (ctx.query("tag") or "").strip()
        needle = query.lower()
        repos = []
        for repo_type in ("model", "dataset", "space"):
            for meta in self.hub.store.list_repos(repo_type):
                if meta.private and not ctx.authenticated:
                    continue
                try:
                    repo = self.hub.store.open(repo_type, meta.repo_id)
                    head = repo.head()
                    card = self.hub._card_data(repo, head)
                    tags = card_tags(card)
                    if tag and tag not in tags:
                        continue
                    if needle and needle not in meta.repo_id.lower() and not any(needle in t.lower() for t in tags):
                        continue
                    thumb = _thumbnail(head)
                    base = "/" + _URL_PREFIX[repo_type] + meta.repo_id
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
        base = "/" + _URL_PREFIX[repo_type] + repo.repo_id
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
        }

    def repo_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str | None, path: str) -> Response:
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
        data = self.hub._card_data(repo, commit) if not path else None
        recent = []
        for i, old in enumerate(repo.history(commit)):
            if i >= RECENT_COMMITS:
                break
            recent.append(old)
        reproductions = sorted(
            (p, e.size) for p, e in commit.files.items() if p.startswith("reproductions/") and p.endswith(".json")
        )
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
            reproductions=reproductions,
            rollout_video=_ROLLOUT_VIDEO if not path and _ROLLOUT_VIDEO in commit.files else None,
            total_size=sum(e.size for e in commit.files.values()),
        )

    def blob_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str, path: str) -> Response:
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
            text = _as_text(data)
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
        code = _highlight_file(path, text)
        with self._guard:
            self._highlights[key] = code
            while len(self._highlights) > _HIGHLIGHT_CACHE_SIZE:
                self._highlights.popitem(last=False)
        return code

    def commits_page(self, ctx: Ctx, repo_type: str, repo_id: str, revision: str) -> Response:
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


# --- helpers ----------------------------------------------------------------------------------


def load_line(repo_id: str, repo_type: str, commit: Commit) -> str:
    """The line that loads this repo pinned to this commit: ``load_env`` for an env repo (one with a
    ``hub_env.json``), else ``snapshot_download``; the same text push_env prints."""
    if repo_type == "model" and "hub_env.json" in commit.files:
        return f'load_env("{repo_id}@{commit.id}", trust_remote_code=True)'
    kind = "" if repo_type == "model" else f', repo_type="{repo_type}"'
    return f'snapshot_download("{repo_id}"{kind}, revision="{commit.id}")'


_FRONT_RE = re.compile(r"\A---[ \t]*\r?\n.*?^---[ \t]*(?:\r?\n|\Z)", flags=re.S | re.M)


def strip_front_matter(text: str) -> str:
    """The README without its YAML metadata block (shown as tags and results, never as raw text).

    >>> strip_front_matter("---\\ntags: [a]\\n---\\n# Title\\n")
    '# Title\\n'
    >>> strip_front_matter("# No metadata\\n")
    '# No metadata\\n'
    """
    match = _FRONT_RE.match(text)
    return text[match.end() :] if match else text


def _thumbnail(commit: Commit) -> str | None:
    if _THUMBNAIL in commit.files:
        return _THUMBNAIL
    gifs = sorted(p for p in commit.files if p.lower().endswith(".gif"))
    return gifs[0] if gifs else None


def _read_text(repo: Repo, commit: Commit, path: str, limit: int = 64 * 1024) -> str | None:
    entry = commit.files.get(path)
    if entry is None:
        return None
    with repo.open_blob(entry) as f:
        return f.read(limit).decode("utf-8", "replace")


def _as_text(data: bytes) -> str | None:
    """``data`` as text, or None if it looks binary (a NUL byte, or not UTF-8)."""
    if b"\x00" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _highlight_file(path: str, text: str) -> str:
    """A file's text as highlighted HTML (Pygments; plain text when no lexer knows the name or the
    file is large). Pygments escapes the text."""
    lexer = None
    if len(text) <= MAX_HIGHLIGHT_BYTES:
        try:
            lexer = get_lexer_for_filename(path.rsplit("/", 1)[-1], stripnl=False)
        except ClassNotFound:
            lexer = None
    if lexer is None:
        lexer = get_lexer_by_name("text", stripnl=False)
    return pygments_highlight(text, lexer, _FILE_FORMATTER)


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
    }


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
