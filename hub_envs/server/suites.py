"""A benchmark suite's task table as the repo page shows it: the ``tasks`` of the env repo's manifest (each task's id,
name, instruction, dataset episodes, fingerprint and its benchmarks' metrics), read generically (the server imports no
client module) and bounded; every value is the publisher's text, escaped by the templates.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from dataclasses import dataclass

from hub_envs.server.formats import ENV_MANIFEST, MANIFEST_TASKS
from hub_envs.server.storage import Commit, Repo

MAX_MANIFEST_BYTES = 4 * 1024 * 1024  # a larger manifest is not read for the page
MAX_TASKS = 500
_TEXT = 300  # characters of a name or an instruction shown
_CACHE_SIZE = 256


@dataclass(frozen=True)
class SuiteTask:
    """One row of the page's task table.

    Attributes:
        index: the task id (its ``task_index``).
        task: its name (the config's ``task`` value).
        instruction: its language instruction.
        episodes: how many dataset episodes it has.
        fingerprint: the first 12 characters of its golden-rollout digest ("" when none).
        metrics: ``(metric, value)`` of the benchmarks declared for it.
    """

    index: str
    task: str
    instruction: str
    episodes: str
    fingerprint: str
    metrics: tuple[tuple[str, str], ...]


def _text(value: object, limit: int = _TEXT) -> str:
    text = " ".join(str(value).split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _value(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else _text(v, 40)


def _rows(data: object) -> list[SuiteTask]:
    if not isinstance(data, dict) or not isinstance(data.get(MANIFEST_TASKS), list):
        return []
    benchmarks = data.get("benchmarks") if isinstance(data.get("benchmarks"), list) else []
    rows = []
    for i, t in enumerate(data[MANIFEST_TASKS][:MAX_TASKS]):
        if not isinstance(t, dict):
            continue
        name = t.get("task")
        fp = t.get("fingerprint") if isinstance(t.get("fingerprint"), dict) else {}
        metrics = [
            (_text(m, 60), _value(v))
            for b in benchmarks
            if isinstance(b, dict) and b.get("task") == name and isinstance(b.get("metrics"), dict)
            for m, v in list(b["metrics"].items())[:20]
        ]
        rows.append(
            SuiteTask(
                index=_text(t.get("task_index", i), 20),
                task=_text(name),
                instruction=_text(t.get("instruction") or ""),
                episodes=str(len(t["episodes"])) if isinstance(t.get("episodes"), list) else "?",
                fingerprint=" ".join(str(fp.get("digest") or "").split())[:12],
                metrics=tuple(metrics),
            )
        )
    return rows


class SuiteTables:
    """Reads the task table of a revision's manifest, cached by the manifest's content (the last 256)."""

    def __init__(self):
        self._cache: OrderedDict[str, list[SuiteTask]] = OrderedDict()
        self._guard = threading.Lock()

    def get(self, repo: Repo, commit: Commit) -> list[SuiteTask]:
        """The suite's tasks at ``commit``.

        Args:
            repo: the repo.
            commit: the shown revision.

        Returns:
            One :class:`SuiteTask` per task; ``[]`` for a one-task env, a repo without a manifest, or one the page
            cannot read (too large, not JSON).
        """
        entry = commit.files.get(ENV_MANIFEST)
        if entry is None or entry.size > MAX_MANIFEST_BYTES:
            return []
        with self._guard:
            if entry.sha256 in self._cache:
                self._cache.move_to_end(entry.sha256)
                return self._cache[entry.sha256]
        with repo.open_blob(entry) as f:
            raw = f.read(MAX_MANIFEST_BYTES)
        try:
            rows = _rows(json.loads(raw))
        except (ValueError, RecursionError):
            rows = []
        with self._guard:
            self._cache[entry.sha256] = rows
            while len(self._cache) > _CACHE_SIZE:
                self._cache.popitem(last=False)
        return rows
