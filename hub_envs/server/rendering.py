"""Markdown and code as safe HTML for the pages: card Markdown rendered by markdown-it-py (raw HTML off) in
worker processes within a time budget, files and code fences highlighted by Pygments."""

from __future__ import annotations

import json
import logging
import os
import posixpath
import re
import subprocess
import sys
import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from urllib.parse import quote, unquote, urlsplit

from markdown_it import MarkdownIt
from markupsafe import escape
from pygments import highlight as pygments_highlight
from pygments.formatters import HtmlFormatter
from pygments.lexers import get_lexer_by_name, get_lexer_for_filename
from pygments.util import ClassNotFound

from hub_envs.server.storage import InvalidPathError, validate_path

logger = logging.getLogger("hub_envs.server")

MAX_HIGHLIGHT_BYTES = 256 * 1024  # highlighted up to this size; plain text above
#: A card's Markdown is rendered in a worker process within this many seconds (env
#: ``HUB_ENVS_SERVER_CARD_RENDER_SECONDS``); past it, the page shows the card as plain text, with a note.
CARD_RENDER_SECONDS = 3.0
_RENDER_WORKERS = 2  # cards rendered at once; a page waits at most the budget for one of them
_RENDER_START_SECONDS = 60.0  # a worker's start (its imports) is not part of a card's budget


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
class Links:
    """How a card's relative links and images resolve: into the repo at the pinned commit."""

    base: str  # /{prefix}{repo_id}
    sha: str
    folders: set[str]  # the commit's folders: a link to one goes to its tree page

    def target(self, url: str) -> str | None:
        """The repo path a relative ``url`` names (``./media/a.gif#x`` -> ``media/a.gif``), or None.

        Args:
            url: a link or image URL from the card.
        """
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
        """An image URL of the card, served from the repo at the pinned commit if it is relative.

        Args:
            url: the image's URL in the card.
        """
        path = self.target(url)
        if path is None:
            return url
        return f"{self.base}/resolve/{self.sha}/{quote(path)}"

    def link(self, url: str) -> str:
        """A link of the card, to the file or folder page at the pinned commit if it is relative.

        Args:
            url: the link's URL in the card.
        """
        path = self.target(url)
        if path is None:
            return url
        fragment = urlsplit(url).fragment
        kind = "tree" if path in self.folders else "blob"
        return f"{self.base}/{kind}/{self.sha}/{quote(path)}" + (f"#{fragment}" if fragment else "")


def render_markdown(text: str, links: Links | None = None) -> str:
    """Card Markdown as HTML: raw HTML escaped, relative images served from the repo at the pinned
    commit, relative links to the file pages, table alignment as classes (the page's CSP allows no
    inline style).

    Args:
        text: the card's Markdown (front matter already cut off).
        links: where relative links and images point; None leaves them as written.

    Returns:
        The HTML.

    >>> render_markdown("Hi <script>alert(1)</script> [x](javascript:alert(1))")
    '<p>Hi &lt;script&gt;alert(1)&lt;/script&gt; [x](javascript:alert(1))</p>\\n'
    >>> links = Links("/alice/env", "a" * 40, folders=set())
    >>> render_markdown("![roll](media/a.gif)", links)
    '<p><img src="/alice/env/resolve/aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa/media/a.gif" alt="roll" /></p>\\n'
    >>> "<thead>" in render_markdown("| | |\\n|---|---|\\n| repo | a/b |\\n")  # a header row of empty cells: none
    False
    """
    md = _markdown()
    tokens = _without_empty_headers(md.parse(text))
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


def _without_empty_headers(tokens: list) -> list:
    """The tokens without the header row of tables whose header cells are all empty (``| | |``, a common way to
    write a two-column table of facts): rendered, it would be an empty shaded row."""
    out, i = [], 0
    while i < len(tokens):
        if tokens[i].type == "thead_open":
            end = next(j for j in range(i, len(tokens)) if tokens[j].type == "thead_close")
            cells = [t for t in tokens[i:end] if t.type == "inline"]
            if all(not (t.content or "").strip() for t in cells):
                i = end + 1  # drop thead_open ... thead_close
                continue
        out.append(tokens[i])
        i += 1
    return out


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
        code = f"from hub_envs.server.rendering import render_worker; render_worker({child_reads}, {child_writes})"
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

    def render(self, text: str, links: Links) -> str:
        """The HTML of card Markdown ``text`` (as :func:`render_markdown` makes it).

        Args:
            text: the card's Markdown (front matter already cut off).
            links: where relative links and images point.

        Returns:
            The HTML.

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
    each request and answer it.

    Args:
        read_fd: the pipe requests arrive on.
        write_fd: the pipe answers go to.
    """
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
            links = Links(request["base"], request["sha"], set(request["folders"]))
            answer = {"html": render_markdown(request["text"], links)}
        except Exception as err:  # a bug in rendering: the page shows the card as text and the log says why
            answer = {"error": f"{type(err).__name__}: {str(err)[:300]}"}
        answers.send_bytes(json.dumps(answer).encode())


def plain_card(text: str) -> str:
    """Card Markdown shown as it is written, escaped: what a page shows when the card cannot be rendered.

    Args:
        text: the card's Markdown.

    >>> plain_card("# Hi <script>")
    '<pre class="card-plain"># Hi &lt;script&gt;</pre>'
    """
    return f'<pre class="card-plain">{escape(text)}</pre>'


def as_text(data: bytes) -> str | None:
    """``data`` as text, or None if it looks binary (a NUL byte, or not UTF-8).

    Args:
        data: a file's bytes.
    """
    if b"\x00" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def highlight_file(path: str, text: str) -> str:
    """A file's text as highlighted HTML (Pygments; plain text when no lexer knows the name or the
    file is large). Pygments escapes the text.

    Args:
        path: the file's path (its name picks the lexer).
        text: its text.
    """
    lexer = None
    if len(text) <= MAX_HIGHLIGHT_BYTES:
        try:
            lexer = get_lexer_for_filename(path.rsplit("/", 1)[-1], stripnl=False)
        except ClassNotFound:
            lexer = None
    if lexer is None:
        lexer = get_lexer_by_name("text", stripnl=False)
    return pygments_highlight(text, lexer, _FILE_FORMATTER)
