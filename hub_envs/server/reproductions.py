"""Reproduction attestations as the pages show them: the ``reproductions/*.json`` records of a revision and of
the open pull requests, read generically (the server imports no client module), with who attested taken from
the server's own data (the pull request's author, or the commit's), never from the record's self-declared field.
"""

from __future__ import annotations

import json
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass

from hub_envs.server.storage import Commit, FileEntry, PullRequest, Repo

DIR = "reproductions/"
SIG = ".sig"
MAX_RECORD_BYTES = 1024 * 1024  # a larger record is not read
_HEX40 = re.compile(r"^[0-9a-f]{40}$")
_CACHE_SIZE = 1024
MAX_TASKS = 500  # a suite's tasks shown per record


@dataclass(frozen=True)
class Record:
    """What a page shows of one attestation file (``reproductions/<date>-<stack>.json``).

    Attributes:
        path: the file's path.
        sha: the env commit it attests (None when the file is not a readable record).
        verdict: ``REPRODUCED`` or ``NOT REPRODUCED`` (or None).
        stack_digest: the 12-hex name of the stack it ran on.
        stack: the stack in one line (python, lerobot, torch... on the platform).
        created_at: when it was made.
        declared_by: the ``attested_by`` the file declares (not trusted: shown as declared).
        error: why the file cannot be read, or None.
        tasks: a benchmark suite's ``(task, reproduced)`` per task, as the record declares them (empty: one task).
    """

    path: str
    sha: str | None
    verdict: str | None
    stack_digest: str | None
    stack: str
    created_at: str
    declared_by: str | None
    error: str | None = None
    tasks: tuple[tuple[str, bool], ...] = ()

    @property
    def reproduced(self) -> bool:
        return self.verdict == "REPRODUCED"

    @property
    def tasks_reproduced(self) -> int:
        """How many of a suite's tasks reproduced."""
        return sum(ok for _, ok in self.tasks)


@dataclass(frozen=True)
class Attested:
    """A record, where it was found and who attested it (from the server's data).

    Attributes:
        record: the record.
        signed: a ``.sig`` file lies next to it (present, not verified here: the server has no allowed signers).
        by: the account that published it: the pull request's author, or the author of the commit that added it.
        pr: the pull request that holds it (open) or that brought it (merged), or None (committed directly).
        merged: on the shown revision (True), or only in an open pull request (False).
        url: the page of its record: the pull request's page, or the file's page at the shown revision.
    """

    record: Record
    signed: bool
    by: str | None
    pr: PullRequest | None
    merged: bool
    url: str


def is_record(path: str) -> bool:
    """Whether ``path`` is an attestation file (``reproductions/*.json``, at any depth under it).

    Args:
        path: a path in a repo.
    """
    return path.startswith(DIR) and path.endswith(".json")


class Records:
    """Reads attestation records, cached by their content (the last 1024)."""

    def __init__(self):
        self._cache: OrderedDict[str, Record] = OrderedDict()
        self._guard = threading.Lock()

    def read(self, repo: Repo, path: str, entry: FileEntry) -> Record:
        """The record of ``path``.

        Args:
            repo: the repo holding it.
            path: its path.
            entry: its file entry.

        Returns:
            The record; a file that is not a readable attestation gives a record with ``error`` set.
        """
        key = f"{entry.sha256}:{path}"
        with self._guard:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        record = _parse(repo, path, entry)
        with self._guard:
            self._cache[key] = record
            while len(self._cache) > _CACHE_SIZE:
                self._cache.popitem(last=False)
        return record

    def attested(self, repo: Repo, commit: Commit, base_url: str) -> list[Attested]:
        """Every attestation of ``repo`` as seen from ``commit``: those in its tree (merged), then those of open
        pull requests that add or change one (a file equal to the shown revision's is listed once, as merged).

        Args:
            repo: the repo.
            commit: the shown revision.
            base_url: the repo's page URL (``/{user}/{repo}``), for the links.

        Returns:
            The attestations, merged first, each with who attested it.
        """
        prs = repo.pull_requests()
        brought: dict[tuple[str, str], PullRequest] = {}  # (path, sha256) -> the merged pull request that added it
        for pr in prs:
            if pr.status == "merged":
                for path, entry in _changed(repo, pr).items():
                    brought.setdefault((path, entry.sha256), pr)
        out = []
        paths = sorted(p for p in commit.files if is_record(p))
        added_by = repo.last_commits(commit, [p for p in paths if (p, commit.files[p].sha256) not in brought]) if paths else {}
        for path in paths:
            entry = commit.files[path]
            pr = brought.get((path, entry.sha256))
            by = pr.author if pr is not None else (added_by[path].author if path in added_by else None)
            url = f"{base_url}/blob/{commit.id}/{path}"
            out.append(Attested(self.read(repo, path, entry), path + SIG in commit.files, by, pr, True, url))
        for pr in sorted(prs, key=lambda p: p.num):
            if pr.status != "open":
                continue
            head = repo.load_commit(pr.head)
            for path, entry in sorted(_changed(repo, pr).items()):
                if commit.files.get(path) == entry:
                    continue
                url = f"{base_url}/discussions/{pr.num}"
                out.append(Attested(self.read(repo, path, entry), path + SIG in head.files, pr.author, pr, False, url))
        return out


def matrix(attested: list[Attested]) -> dict:
    """The matrix env revision x stack -> attestations, as the repo page draws it.

    Args:
        attested: what :meth:`Records.attested` returned.

    Returns:
        ``{"revisions": [sha...], "stacks": [(digest, description)...], "cells": {(sha, digest): [Attested...]},
        "unreadable": [Attested...]}``; revisions and stacks in order of first appearance.
    """
    good = [a for a in attested if a.record.error is None]
    revisions = list(dict.fromkeys(a.record.sha for a in good))
    stacks = list(dict.fromkeys((a.record.stack_digest, a.record.stack) for a in good))
    cells: dict[tuple, list[Attested]] = {}
    for a in good:
        cells.setdefault((a.record.sha, a.record.stack_digest), []).append(a)
    return {"revisions": revisions, "stacks": stacks, "cells": cells, "unreadable": [a for a in attested if a.record.error]}


def _changed(repo: Repo, pr: PullRequest) -> dict[str, FileEntry]:
    """The attestation files a pull request adds or changes (its head against where it started)."""
    base, head = repo.load_commit(pr.base), repo.load_commit(pr.head)
    return {p: e for p, e in head.files.items() if is_record(p) and base.files.get(p) != e}


def _parse(repo: Repo, path: str, entry: FileEntry) -> Record:
    def bad(why: str) -> Record:
        return Record(path, None, None, None, "", "", None, error=why)

    if entry.size > MAX_RECORD_BYTES:
        return bad(f"larger than {MAX_RECORD_BYTES // 1024} KiB")
    with repo.open_blob(entry) as f:
        raw = f.read(MAX_RECORD_BYTES)
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError):
        return bad("not valid JSON")
    if not isinstance(data, dict) or data.get("kind") != "hub-envs reproduction attestation":
        return bad("not a hub-envs reproduction attestation")
    sha, verdict, digest = data.get("sha"), data.get("verdict"), data.get("stack_digest")
    if not (isinstance(sha, str) and _HEX40.match(sha)):
        return bad("its 'sha' is not a commit id")
    if verdict not in ("REPRODUCED", "NOT REPRODUCED"):
        return bad("its 'verdict' is neither REPRODUCED nor NOT REPRODUCED")
    if not (isinstance(digest, str) and re.fullmatch(r"[0-9a-f]{6,64}", digest)):
        return bad("its 'stack_digest' is not a digest")
    tasks = data.get("tasks", [])
    if not (isinstance(tasks, list) and all(isinstance(t, dict) and isinstance(t.get("reproduced"), bool) for t in tasks)):
        return bad("its 'tasks' is not a list of task verdicts")
    if tasks and (verdict == "REPRODUCED") != all(t["reproduced"] for t in tasks):
        return bad("its 'verdict' contradicts its tasks' verdicts")
    stack = data.get("stack") if isinstance(data.get("stack"), dict) else {}
    declared = data.get("attested_by")
    created = data.get("created_at")
    return Record(
        path,
        sha,
        verdict,
        digest,
        describe_stack(stack),
        str(created)[:40] if isinstance(created, str) else "",
        str(declared)[:100] if isinstance(declared, str) else None,
        tasks=tuple((" ".join(str(t.get("task"))[:200].split()), t["reproduced"]) for t in tasks[:MAX_TASKS]),
    )


def describe_stack(stack: dict) -> str:
    """A stack in one line: ``python 3.13.1, lerobot 0.6.1, torch 2.11.0, numpy 2.2.6 on Linux x86_64``.

    Args:
        stack: the record's ``stack``.

    >>> describe_stack({"python": "3.13.1", "packages": {"lerobot": "0.6.1"}, "platform": "Linux-6.1", "machine": "x86_64"})
    'python 3.13.1, lerobot 0.6.1 on Linux x86_64'
    """
    packages = stack.get("packages") if isinstance(stack.get("packages"), dict) else {}
    simulator = stack.get("simulator") if isinstance(stack.get("simulator"), dict) else {}
    parts = [f"python {stack.get('python')}"]
    parts += [f"{n} {packages[n]}" for n in ("lerobot", "torch", "numpy", "gymnasium") if n in packages]
    parts += [f"{n} {v}" for n, v in sorted(simulator.items())[:5]]
    system = str(stack.get("platform", "")).split("-")[0]
    text = ", ".join(str(p) for p in parts) + f" on {system} {stack.get('machine') or ''}".rstrip()
    return text[:300]
