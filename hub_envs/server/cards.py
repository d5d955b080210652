"""README metadata (the Hub's ``cardData``): the YAML front matter parsed with limits and cached by README
content, and what the pages show of a card (title line, tags, fields, evaluation results)."""

from __future__ import annotations

import base64
import datetime
import json
import logging
import math
import re
import threading
from collections import OrderedDict
from typing import Any

import yaml

from hub_envs.server.storage import Commit, Repo

logger = logging.getLogger("hub_envs.server")

#: The front matter is parsed from at most this many bytes of YAML; a larger block is left out.
CARD_MAX_BYTES = 64 * 1024
CARD_MAX_DEPTH = 64
_CACHE_SIZE = 1024
_FRONT_MATTER_RE = re.compile(r"^---[ \t]*\r?\n(.*?)(?:\r?\n)?^---[ \t]*$", flags=re.S | re.M)
_FRONT_RE = re.compile(r"\A---[ \t]*\r?\n.*?^---[ \t]*(?:\r?\n|\Z)", flags=re.S | re.M)


class CardLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader with limits for README metadata: no aliases (``*name``: a few hundred
    bytes of aliases expand to gigabytes once written as JSON, the "billion laughs"), and nesting
    at most ``CARD_MAX_DEPTH`` deep (the composer recurses once per level)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        """PyYAML's ``compose_node``, refusing aliases and nesting past the limit.

        Args:
            parent: the parent node (PyYAML's).
            index: the index in the parent (PyYAML's).

        Raises:
            yaml.composer.ComposerError: an alias, or nesting deeper than ``CARD_MAX_DEPTH``.
        """
        if self.check_event(yaml.AliasEvent):
            raise yaml.composer.ComposerError(
                None, None, "YAML aliases (*name) are not allowed in card metadata", self.peek_event().start_mark
            )
        if self._depth >= CARD_MAX_DEPTH:
            raise yaml.composer.ComposerError(
                None, None, f"card metadata nested more than {CARD_MAX_DEPTH} levels deep", self.peek_event().start_mark
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def front_matter(text: str, strict: bool = False, truncated: bool = False) -> dict | None:
    """The YAML metadata block at the top of a README (``---`` ... ``---``), parsed with limits: at most
    :data:`CARD_MAX_BYTES` (UTF-8) of YAML, no aliases, bounded nesting.

    Args:
        text: the README (or its start).
        strict: raise instead of returning None when the block is malformed or over a limit.
        truncated: ``text`` is only the start of the README.

    Returns:
        The metadata, or None (no block; or, unless ``strict``, a block that is malformed or over a limit).

    Raises:
        ValueError: ``strict``, and the block is malformed or over a limit; the message is for the card's author.

    >>> front_matter("---\\ntags: [a]\\n---\\n# Title\\n")
    {'tags': ['a']}
    """
    if not text.startswith("---"):
        return None
    window = text[: CARD_MAX_BYTES + 1024]
    match = _FRONT_MATTER_RE.match(window)
    if not match:
        if not strict:
            return None
        if truncated or len(text) > len(window):
            raise ValueError(
                f"The YAML metadata block is not closed within its first {CARD_MAX_BYTES // 1024} KiB: close it "
                "with a line '---', and keep the metadata under that size."
            )
        raise ValueError("The YAML metadata block is not closed: add a line with '---' after it.")
    block = match.group(1)
    if len(block.encode("utf-8", "replace")) > CARD_MAX_BYTES:
        if strict:
            raise ValueError(f"The YAML metadata block is larger than {CARD_MAX_BYTES // 1024} KiB.")
        return None
    try:
        meta = yaml.load(block, Loader=CardLoader)  # noqa: S506 - a SafeLoader, with limits
    except yaml.YAMLError as err:
        if strict:
            raise ValueError(f"Invalid YAML in the metadata block: {err}") from None
        return None
    except (ValueError, TypeError, OverflowError, RecursionError) as err:  # e.g. a date such as 2024-02-30
        if strict:
            raise ValueError(f"Invalid value in the metadata block: {short_error(err)}") from None
        return None
    if meta is not None and not isinstance(meta, dict):
        if strict:
            raise ValueError("The YAML metadata block must be a mapping (key: value lines).")
        return None
    return meta


def jsonable(obj: Any) -> Any:
    """YAML data as JSON data, as the Hub reports ``cardData``: dates as ISO strings, sets as lists,
    binary as base64, keys as strings, NaN and infinities as null. (Depth is bounded by the loader.)

    Args:
        obj: data from the YAML loader.

    Returns:
        The same data, made of JSON types only.
    """
    if isinstance(obj, dict):
        return {_json_key(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (set, frozenset)):
        return [jsonable(v) for v in sorted(obj, key=repr)]
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
    value = jsonable(key)
    return value if isinstance(value, str) else json.dumps(value)


def short_error(err: BaseException) -> str:
    """``Type: message``, the message cut at 300 characters: for logs and error messages.

    Args:
        err: the exception.
    """
    return f"{type(err).__name__}: {str(err)[:300]}"


class CardData:
    """Each repo's README metadata as JSON-ready data, cached by README content (the last 1024 READMEs)."""

    def __init__(self):
        self._cards: OrderedDict[str, dict | None] = OrderedDict()  # README sha256 -> cardData
        self._guard = threading.Lock()

    def get(self, repo: Repo, commit: Commit) -> dict | None:
        """The ``cardData`` of ``commit``'s README.

        Args:
            repo: the repo.
            commit: the commit whose README to read.

        Returns:
            The metadata, or None: no README, no metadata, or metadata over the limits or invalid (logged).
        """
        entry = commit.files.get("README.md")
        if entry is None:
            return None
        with self._guard:
            if entry.sha256 in self._cards:
                self._cards.move_to_end(entry.sha256)
                return self._cards[entry.sha256]
        card = None
        try:
            with repo.open_blob(entry) as f:  # the front matter must fit in the first bytes
                head = f.read(CARD_MAX_BYTES + 1024)
            meta = front_matter(head.decode("utf-8", "replace"), truncated=entry.size > len(head))
            card = jsonable(meta) if isinstance(meta, dict) else None
        except Exception as err:  # over a limit, invalid, or a bug: no cardData for this repo
            logger.warning(
                "Ignoring the README metadata of %s %s (README %s): %s",
                repo.repo_type,
                repo.repo_id,
                entry.oid[:12],
                short_error(err),
            )
        with self._guard:
            self._cards[entry.sha256] = card
            while len(self._cards) > _CACHE_SIZE:
                self._cards.popitem(last=False)
        return card


# --- what the pages show of a card ------------------------------------------------------------------


def strip_front_matter(text: str) -> str:
    """The README without its YAML metadata block (shown as tags and results, never as raw text).

    Args:
        text: the README.

    Returns:
        The README from the line after the block's closing ``---``, or ``text`` when it has none.

    >>> strip_front_matter("---\\ntags: [a]\\n---\\n# Title\\n")
    '# Title\\n'
    >>> strip_front_matter("# No metadata\\n")
    '# No metadata\\n'
    """
    match = _FRONT_RE.match(text)
    return text[match.end() :] if match else text


def card_title(body: str) -> str | None:
    """The card's title line: its first ``# heading`` (front matter already cut off).

    Args:
        body: the card's Markdown without its front matter.

    Returns:
        The heading's text, or None (no ``#`` heading in the first 200 lines).

    >>> card_title("Intro\\n\\n# tiny-env — a hub-envs environment\\n## Load it")
    'tiny-env — a hub-envs environment'
    """
    for line in body.splitlines()[:200]:
        if line.startswith("# "):
            return line[2:].strip().strip("#").strip() or None
    return None


def eval_results(card: dict | None) -> list[dict]:
    """The evaluation results of a card's ``model-index`` metadata, one row per metric.

    Args:
        card: the card's metadata (``cardData``), or None.

    Returns:
        ``{model, task, dataset, metric, value, verified}`` rows (at most 20 models x 50 results x 50 metrics).

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
    tags and model-index are shown on their own.

    Args:
        card: the card's metadata (``cardData``), or None.

    Returns:
        At most 20 rows, values cut at 200 characters.
    """
    if not isinstance(card, dict):
        return []
    out = []
    for key, value in card.items():
        if key in ("tags", "model-index") or isinstance(value, (dict, list)) or value is None:
            continue
        out.append((str(key), str(value)[:200]))
    return out[:20]


def card_tags(card: dict | None) -> list[str]:
    """The card metadata's ``tags`` (at most 50), as strings.

    Args:
        card: the card's metadata (``cardData``), or None.

    Returns:
        The tags; empty when there are none.
    """
    tags = card.get("tags") if isinstance(card, dict) else None
    return [str(t) for t in tags[:50]] if isinstance(tags, list) else []
