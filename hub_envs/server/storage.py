"""The on-disk store behind the loopback Hub server: repos, blobs, commits, refs and pull requests, with
git's identifiers; atomic writes, one process per root. No HTTP here. Its layout: ``docs/server.md#the-store``.

Example:
    >>> import tempfile
    >>> from hub_envs.server.storage import AddFile, Change, HubStore
    >>> store = HubStore(tempfile.mkdtemp())
    >>> repo = store.create_repo("model", "alice/pendulum", author="alice")
    >>> entry = repo.write_blob(b"print('hi')\\n")
    >>> commit = repo.commit("main", Change([AddFile("env.py", entry)], title="Add env", author="alice"))
    >>> sorted(repo.resolve("main").files)
    ['.gitattributes', 'env.py']
    >>> repo.resolve(commit.id).id == commit.id
    True
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

FORMAT = "hub-envs-store 1"
REPO_TYPES = ("model", "dataset", "space")
DEFAULT_BRANCH = "main"
_HEX40 = re.compile(r"^[0-9a-f]{40}$")
_PR_REF = re.compile(r"^refs/pr/[1-9][0-9]{0,8}$")
_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,95}")  # fullmatch: "$" would let a trailing newline through
_RESERVED_NAMESPACES = {"api", "models", "datasets", "spaces", "resolve", "tree", "blob"}
_MAX_PATH_LEN = 1024
_MAX_SEGMENT_BYTES = 255  # NAME_MAX of ext4, APFS, NTFS...: a longer name cannot be checked out
_CONTROL_RE = re.compile(r"[\x00-\x1f\x7f-\x9f]")

# What the Hub commits as ".gitattributes" when it creates a repo: its default LFS patterns (those of
# a model repo, and the image, audio and video patterns of a dataset repo: env repos hold datasets).
# The preupload answer follows them (see hub_envs.server.lfs).
_LFS_PATTERNS = (
    "*.7z *.arrow *.bin *.bz2 *.ckpt *.ftz *.gz *.h5 *.joblib *.lfs.* *.lz4 *.mds *.mlmodel *.model *.msgpack *.npy "
    "*.npz *.onnx *.ot *.parquet *.pb *.pickle *.pkl *.pt *.pth *.rar *.safetensors saved_model/**/* *.tar.* *.tar "
    "*.tflite *.tgz *.wasm *.xz *.zip *.zst *tfevents*"
)
_LFS_MEDIA = (
    ("Audio files - uncompressed", "*.pcm *.sam *.raw"),
    ("Audio files - compressed", "*.aac *.flac *.mp3 *.ogg *.wav"),
    ("Image files - uncompressed", "*.bmp *.gif *.png *.tiff"),
    ("Image files - compressed", "*.jpg *.jpeg *.webp"),
    ("Video files - compressed", "*.mp4 *.webm"),
)
DEFAULT_GITATTRIBUTES = (
    "".join(f"{p} filter=lfs diff=lfs merge=lfs -text\n" for p in _LFS_PATTERNS.split())
    + "".join(
        f"# {title}\n" + "".join(f"{p} filter=lfs diff=lfs merge=lfs -text\n" for p in patterns.split())
        for title, patterns in _LFS_MEDIA
    )
).encode()


# --- errors -----------------------------------------------------------------------------------


class StoreError(Exception):
    """Base class of every error the store raises on purpose."""


class InvalidNameError(StoreError, ValueError):
    """A repo id, repo type, branch or tag name is malformed."""


class InvalidPathError(StoreError, ValueError):
    """A path in a repo is malformed or tries to escape the repo (``..``, absolute, ``\\``, NUL...)."""


class RepoNotFoundError(StoreError, LookupError):
    """No repo with this type and id."""


class RepoExistsError(StoreError):
    """A repo with this type and id already exists."""


class RevisionNotFoundError(StoreError, LookupError):
    """No branch, tag or commit with this name in the repo."""


class EntryNotFoundError(StoreError, LookupError):
    """No file or folder at this path in this revision."""


class RefExistsError(StoreError):
    """The branch or tag already exists."""


class ParentMismatchError(StoreError):
    """The branch moved since the commit the caller based its change on (``parent_commit``)."""


class InvalidOperationError(StoreError, ValueError):
    """A commit operation or ref change that cannot be applied (file/folder clash, deleting main...)."""


class PullRequestNotFoundError(StoreError, LookupError):
    """No pull request (discussion) with this number in the repo."""


class MergeConflictError(StoreError):
    """A pull request changes files its target branch changed too since the pull request started."""

    def __init__(self, message: str, files: Sequence[str]):
        super().__init__(message)
        self.files = list(files)


# --- identifiers ------------------------------------------------------------------------------


def git_blob_oid(data: bytes) -> str:
    """The git blob sha1 of ``data``: what the Hub uses as ETag and ``oid`` for a regular file.

    Args:
        data: the file's content.
    """
    digest = hashlib.sha1(b"blob %d\0" % len(data))
    digest.update(data)  # not `header + data`: that would copy a large file once more
    return digest.hexdigest()


def lfs_pointer(sha256: str, size: int) -> bytes:
    """The Git LFS pointer file of a blob: what git stores in the tree for a file kept in LFS.

    Args:
        sha256: the content's sha256 (hex).
        size: the content's size in bytes.
    """
    return f"version https://git-lfs.github.com/spec/v1\noid sha256:{sha256}\nsize {size}\n".encode()


def lfs_entry(sha256: str, size: int) -> FileEntry:
    """The :class:`FileEntry` of an LFS file: its git ``oid`` is the pointer's blob sha1.

    Args:
        sha256: the content's sha256 (hex).
        size: the content's size in bytes.
    """
    return FileEntry(oid=git_blob_oid(lfs_pointer(sha256, size)), sha256=sha256, size=size, lfs=True)


def format_date(dt: datetime) -> str:
    """``2024-05-01T12:00:00.123Z``: the only date format huggingface_hub's ``parse_datetime`` expects.

    Args:
        dt: an aware datetime (converted to UTC).
    """
    dt = dt.astimezone(UTC)
    return dt.strftime("%Y-%m-%dT%H:%M:%S.") + f"{dt.microsecond // 1000:03d}Z"


def now() -> datetime:
    return datetime.now(UTC)


def validate_repo_type(repo_type: str) -> str:
    """Check a repo type: ``model``, ``dataset`` or ``space``.

    Args:
        repo_type: the type.

    Returns:
        ``repo_type``.

    Raises:
        InvalidNameError: another type.
    """
    if repo_type not in REPO_TYPES:
        raise InvalidNameError(f"Invalid repo type {repo_type!r}: expected one of {', '.join(REPO_TYPES)}.")
    return repo_type


def validate_repo_id(repo_id: str) -> tuple[str, str]:
    """Split ``namespace/name`` and check both parts.

    Args:
        repo_id: ``namespace/name``.

    Returns:
        ``(namespace, name)``.

    Raises:
        InvalidNameError: malformed, or a reserved namespace; the message says the rules.
    """
    parts = repo_id.split("/")
    if len(parts) != 2:
        raise InvalidNameError(
            f"Invalid repo id {repo_id!r}: expected 'namespace/name' (this server has no namespace-less repos)."
        )
    for part in parts:
        if not _NAME_RE.fullmatch(part) or "--" in part or ".." in part or part.endswith(".git"):
            raise InvalidNameError(
                f"Invalid repo id {repo_id!r}: each part must be 1-96 characters among letters, digits, '-', '_' "
                "and '.', start with a letter or digit, and contain neither '--' nor '..' nor end with '.git'."
            )
    if parts[0].lower() in _RESERVED_NAMESPACES:
        raise InvalidNameError(f"Invalid repo id {repo_id!r}: namespace {parts[0]!r} is reserved.")
    return parts[0], parts[1]


def validate_path(path: str) -> str:
    """Check a path inside a repo (``a/b.txt``): it must not be able to escape the repo.

    Refused: empty, absolute, backslashes, control characters (C0, DEL and C1: U+0000-U+001F,
    U+007F-U+009F), text that is not valid Unicode (lone surrogates), empty / ``.`` / ``..``
    segments, a ``.git`` segment, segments over 255 bytes (UTF-8; what file systems store), and
    over-long paths.

    Args:
        path: a path inside a repo.

    Returns:
        ``path``.

    Raises:
        InvalidPathError: the path is refused; the message says why.
    """
    if not isinstance(path, str) or not path:
        raise InvalidPathError("Invalid path: empty.")
    if len(path) > _MAX_PATH_LEN:
        raise InvalidPathError(f"Invalid path: longer than {_MAX_PATH_LEN} characters.")
    if _CONTROL_RE.search(path):
        raise InvalidPathError(
            f"Invalid path {path!r}: contains a control character (C0 such as NUL or newline, DEL, or C1 U+0080-U+009F)."
        )
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise InvalidPathError(f"Invalid path {path!r}: not valid Unicode (lone surrogate).") from None
    if "\\" in path:
        raise InvalidPathError(f"Invalid path {path!r}: backslashes are not allowed; use '/'.")
    if path.startswith("/"):
        raise InvalidPathError(f"Invalid path {path!r}: must be relative to the repo root.")
    for segment in path.split("/"):
        if segment in ("", ".", ".."):
            raise InvalidPathError(f"Invalid path {path!r}: empty, '.' and '..' segments are not allowed.")
        if segment == ".git":
            raise InvalidPathError(f"Invalid path {path!r}: '.git' is reserved.")
        if len(segment.encode("utf-8")) > _MAX_SEGMENT_BYTES:
            raise InvalidPathError(
                f"Invalid path {path[:80]!r}...: a file or folder name is longer than {_MAX_SEGMENT_BYTES} bytes (UTF-8)."
            )
    return path


def validate_ref_name(name: str, kind: str = "branch") -> str:
    """Check a branch or tag name with git's rules (``git check-ref-format``), simplified.

    Args:
        name: the branch or tag name.
        kind: ``"branch"`` or ``"tag"``, for the message.

    Returns:
        ``name``.

    Raises:
        InvalidNameError: not a valid git ref name, or 40 hex digits (it would shadow commit ids).
    """
    bad = (
        not name
        or len(name) > 255
        or name.startswith(("/", "-", "."))
        or name.endswith(("/", ".", ".lock"))
        or ".." in name
        or "//" in name
        or "@{" in name
        or name == "@"
        or any(ord(c) < 0x21 or 0x7F <= ord(c) <= 0x9F or 0xD800 <= ord(c) <= 0xDFFF or c in "~^:?*[\\" for c in name)
        or any(seg.startswith(".") for seg in name.split("/"))
    )
    if bad:
        raise InvalidNameError(f"Invalid {kind} name {name!r}: it must be a valid git ref name.")
    if _HEX40.match(name.lower()):
        raise InvalidNameError(f"Invalid {kind} name {name!r}: a 40-hex name would shadow commit ids.")
    return name


# --- data -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FileEntry:
    """A file in a commit's tree: its git blob ``oid`` (sha1), ``sha256`` (the blob's address) and ``size``.

    ``lfs``: the file was committed through Git LFS (an ``lfsFile`` line). Git then holds a pointer
    file (see :func:`lfs_pointer`), so ``oid`` is the git blob sha1 of the *pointer*, as on the Hub;
    the content is the blob ``sha256``.
    """

    oid: str
    sha256: str
    size: int
    lfs: bool = False

    @property
    def pointer_size(self) -> int | None:
        """Size of the LFS pointer file git holds (None for a regular file)."""
        return len(lfs_pointer(self.sha256, self.size)) if self.lfs else None


@dataclass(frozen=True)
class Commit:
    """An immutable commit: the whole tree (path -> :class:`FileEntry`), parents, message, author, date."""

    id: str
    tree_oid: str
    parents: tuple[str, ...]
    title: str
    message: str
    author: str
    date: str
    files: Mapping[str, FileEntry]

    def to_json(self) -> bytes:
        return json.dumps(
            {
                "id": self.id,
                "tree": self.tree_oid,
                "parents": list(self.parents),
                "title": self.title,
                "message": self.message,
                "author": self.author,
                "date": self.date,
                "files": {p: [e.oid, e.sha256, e.size, *([1] if e.lfs else [])] for p, e in sorted(self.files.items())},
            },
            separators=(",", ":"),
        ).encode()

    @classmethod
    def from_json(cls, data: bytes) -> Commit:
        """A commit from what :meth:`to_json` wrote.

        Args:
            data: the commit object's JSON.
        """
        d = json.loads(data)
        return cls(
            id=d["id"],
            tree_oid=d["tree"],
            parents=tuple(d["parents"]),
            title=d["title"],
            message=d["message"],
            author=d["author"],
            date=d["date"],
            files={p: FileEntry(v[0], v[1], v[2], bool(v[3]) if len(v) > 3 else False) for p, v in d["files"].items()},
        )


@dataclass
class RepoMeta:
    """What ``repo.json`` holds."""

    repo_type: str
    repo_id: str
    private: bool
    created_at: str
    author: str
    sdk: str | None = None

    def to_json(self) -> bytes:
        return json.dumps(
            {
                "type": self.repo_type,
                "id": self.repo_id,
                "private": self.private,
                "createdAt": self.created_at,
                "author": self.author,
                "sdk": self.sdk,
            },
            indent=1,
        ).encode()

    @classmethod
    def from_json(cls, data: bytes) -> RepoMeta:
        """The metadata from what :meth:`to_json` wrote.

        Args:
            data: ``repo.json``'s bytes.
        """
        d = json.loads(data)
        return cls(d["type"], d["id"], bool(d["private"]), d["createdAt"], d["author"], d.get("sdk"))


PR_STATUSES = ("open", "closed", "merged")


@dataclass(frozen=True)
class PullRequest:
    """A pull request: ``refs/pr/<num>``, its ``head`` commit, the branch it targets and its story.

    ``base`` is the commit of ``target`` it started from (the merge base); ``events`` are the Hub's
    discussion events (``{"id", "type", "createdAt", "author", "data"}``: the opening comment, commits,
    status changes).
    """

    num: int
    title: str
    author: str
    created_at: str
    status: str
    target: str
    base: str
    head: str
    events: tuple[dict, ...] = ()
    merge_commit: str | None = None

    def to_json_obj(self) -> dict:
        return {
            "num": self.num,
            "title": self.title,
            "author": self.author,
            "createdAt": self.created_at,
            "status": self.status,
            "target": self.target,
            "base": self.base,
            "head": self.head,
            "events": list(self.events),
            "mergeCommitId": self.merge_commit,
        }

    @classmethod
    def from_json_obj(cls, d: dict) -> PullRequest:
        """A pull request from what :meth:`to_json_obj` wrote.

        Args:
            d: the pull request's entry in ``refs.json``.
        """
        return cls(
            int(d["num"]),
            d["title"],
            d["author"],
            d["createdAt"],
            d["status"],
            d["target"],
            d["base"],
            d["head"],
            tuple(d.get("events", ())),
            d.get("mergeCommitId"),
        )


@dataclass
class Refs:
    """Branches (name -> sha), tags (name -> sha, with an optional message) and pull requests (num -> PR)."""

    branches: dict[str, str] = field(default_factory=dict)
    tags: dict[str, str] = field(default_factory=dict)
    tag_messages: dict[str, str] = field(default_factory=dict)
    pulls: dict[int, PullRequest] = field(default_factory=dict)

    def to_json(self) -> bytes:
        tags = {name: {"target": sha, "message": self.tag_messages.get(name)} for name, sha in self.tags.items()}
        data: dict = {"branches": self.branches, "tags": tags}
        if self.pulls:
            data["pulls"] = {str(n): pr.to_json_obj() for n, pr in self.pulls.items()}
        return json.dumps(data, indent=1, sort_keys=True).encode()

    @classmethod
    def from_json(cls, data: bytes) -> Refs:
        """The refs from what :meth:`to_json` wrote.

        Args:
            data: ``refs.json``'s bytes.
        """
        d = json.loads(data)
        tags = {name: t["target"] for name, t in d.get("tags", {}).items()}
        messages = {name: t["message"] for name, t in d.get("tags", {}).items() if t.get("message")}
        pulls = {int(n): PullRequest.from_json_obj(v) for n, v in d.get("pulls", {}).items()}
        return cls(dict(d.get("branches", {})), tags, messages, pulls)


# Commit operations, applied in order by Repo.commit.
@dataclass(frozen=True)
class AddFile:
    """Add or replace the file at ``path`` with a blob already written by :meth:`Repo.write_blob`."""

    path: str
    entry: FileEntry


@dataclass(frozen=True)
class DeleteFile:
    """Delete the file at ``path``; :class:`EntryNotFoundError` if there is none."""

    path: str


@dataclass(frozen=True)
class DeleteFolder:
    """Delete every file under ``path/``; :class:`EntryNotFoundError` if there is none."""

    path: str


Operation = AddFile | DeleteFile | DeleteFolder


@dataclass(frozen=True)
class Change:
    """What a commit writes, and on whose word: what :meth:`Repo.commit` applies to a branch and
    :meth:`Repo.open_pull_request` opens a pull request with.

    ``operations`` are applied in order; ``parent`` (5 to 40 hex), if given, is the commit the change was made
    against (the optimistic-concurrency check of ``parent_commit``); ``check`` is called with the new tree
    (path -> entry) under the repo lock, before anything is written, and raises (e.g.
    :class:`InvalidOperationError`) to refuse the change.
    """

    operations: Sequence[Operation]
    title: str
    author: str
    message: str = ""
    parent: str | None = None
    check: Callable[[Mapping[str, FileEntry]], None] | None = None


# --- git object hashing -----------------------------------------------------------------------


def _tree_oids(files: Mapping[str, FileEntry]) -> dict[str, str]:
    """The git tree sha1 of every folder of ``files`` ("" is the root)."""
    children: dict[str, dict[str, tuple[str, str]]] = {"": {}}  # folder -> name -> (mode, oid or "")
    for path, entry in files.items():
        parts = path.split("/")
        for depth in range(len(parts) - 1):
            folder = "/".join(parts[:depth])
            sub = "/".join(parts[: depth + 1])
            children.setdefault(folder, {})[parts[depth]] = ("40000", "")
            children.setdefault(sub, {})
        children.setdefault("/".join(parts[:-1]), {})[parts[-1]] = ("100644", entry.oid)
    oids: dict[str, str] = {}
    for folder in sorted(children, key=lambda f: f.count("/") + (1 if f else 0), reverse=True):
        entries = []
        for name, (mode, oid) in children[folder].items():
            if mode == "40000":
                oid = oids[f"{folder}/{name}" if folder else name]
            entries.append((name + "/" if mode == "40000" else name, name, mode, oid))
        body = b"".join(
            mode.encode() + b" " + name.encode() + b"\0" + bytes.fromhex(oid) for _, name, mode, oid in sorted(entries)
        )
        oids[folder] = hashlib.sha1(b"tree %d\0" % len(body) + body).hexdigest()
    return oids


def _commit_oid(tree: str, parents: Sequence[str], author: str, when: datetime, title: str, message: str) -> str:
    ident = f"{author} <{author}@users.noreply.hub-envs> {int(when.timestamp())} +0000"
    text = f"tree {tree}\n" + "".join(f"parent {p}\n" for p in parents)
    text += f"author {ident}\ncommitter {ident}\n\n{title}\n"
    if message:
        text += f"\n{message}\n"
    body = text.encode()
    return hashlib.sha1(b"commit %d\0" % len(body) + body).hexdigest()


# --- the store --------------------------------------------------------------------------------


class HubStore:
    """All repos under one ``root`` folder. Thread-safe; one process per root.

    Args:
        root: the folder; created if missing.
        fsync: fsync every file before moving it into place (durable across power loss, slower).
    """

    def __init__(self, root: str | os.PathLike, *, fsync: bool = True):
        self.root = Path(root).resolve()
        self.fsync = fsync
        self.root.mkdir(parents=True, exist_ok=True)
        fmt = self.root / "FORMAT"
        if not fmt.exists() and any(p.name not in ("tmp", "trash", "repos", "LOCK") for p in self.root.iterdir()):
            raise StoreError(f"{self.root} is not empty and is not a hub-envs store (no FORMAT file): pass an empty folder.")
        self._lock_file = _lock_exclusively(self.root / "LOCK")
        if fmt.exists():
            found = fmt.read_text().strip()
            if found != FORMAT:
                raise StoreError(f"{self.root} holds {found!r}, not {FORMAT!r}: pass another --root.")
        for scratch in ("tmp", "trash"):
            shutil.rmtree(self.root / scratch, ignore_errors=True)
            (self.root / scratch).mkdir()
        (self.root / "repos").mkdir(exist_ok=True)
        if not fmt.exists():
            self.write_atomic(fmt, (FORMAT + "\n").encode())
        self._locks: dict[tuple[str, str], threading.Lock] = {}
        self._locks_guard = threading.Lock()
        self._create_lock = threading.Lock()
        self._commit_cache: OrderedDict[tuple[tuple[str, str], str], Commit] = OrderedDict()
        self._cache_guard = threading.Lock()

    # -- helpers --

    def scratch_path(self, prefix: str = "") -> Path:
        """A fresh path under ``tmp/`` (emptied when a store opens: nothing there is ever served).

        Args:
            prefix: the file name's start (what it is for, in a listing of ``tmp/``).
        """
        return self.root / "tmp" / f"{prefix}{uuid.uuid4().hex}"

    def write_atomic(self, path: Path, data: bytes) -> None:
        """Write ``data`` to ``path`` so readers see the old or the new content, never a mix.

        Args:
            path: the file to (re)place.
            data: its new content.
        """
        tmp = self.root / "tmp" / f"{uuid.uuid4().hex}.tmp"
        with open(tmp, "wb") as f:
            f.write(data)
            if self.fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)

    def _key(self, repo_type: str, repo_id: str) -> tuple[str, str]:
        validate_repo_type(repo_type)
        validate_repo_id(repo_id)
        return repo_type, repo_id.lower()

    def _repo_dir(self, key: tuple[str, str]) -> Path:
        return self.root / "repos" / f"{key[0]}s" / key[1]

    def lock(self, key: tuple[str, str]) -> threading.Lock:
        """The lock of one repo's ``refs.json`` (in-process: one server process per root).

        Args:
            key: the repo's ``(type, lower-cased id)``.
        """
        with self._locks_guard:
            return self._locks.setdefault(key, threading.Lock())

    def cached_commit(self, key: tuple[str, str], sha: str, load) -> Commit:
        """The commit ``sha`` of the repo ``key`` (type, lower-cased id), from the cache or ``load()``.

        Keyed by the repo type too: a model and a dataset may share an id, and one repo must never
        see another's commits (their file names, or a 500 on blobs it does not hold).

        Args:
            key: the repo's ``(type, lower-cased id)``.
            sha: the commit id (40 hex).
            load: reads the commit when it is not cached (the last 512 are).
        """
        cache_key = (key, sha)
        with self._cache_guard:
            commit = self._commit_cache.get(cache_key)
            if commit is not None:
                self._commit_cache.move_to_end(cache_key)
                return commit
        commit = load()
        with self._cache_guard:
            self._commit_cache[cache_key] = commit
            while len(self._commit_cache) > 512:
                self._commit_cache.popitem(last=False)
        return commit

    def _forget(self, key: tuple[str, str]) -> None:
        with self._cache_guard:
            for k in [k for k in self._commit_cache if k[0] == key]:
                del self._commit_cache[k]

    # -- repos --

    def open(self, repo_type: str, repo_id: str) -> Repo:
        """The repo ``repo_id`` of type ``repo_type``.

        Args:
            repo_type: ``model``, ``dataset`` or ``space``.
            repo_id: ``namespace/name`` (any casing).

        Raises:
            RepoNotFoundError: no such repo.
            InvalidNameError: a malformed type or id.
        """
        key = self._key(repo_type, repo_id)
        path = self._repo_dir(key)
        try:
            meta = RepoMeta.from_json((path / "repo.json").read_bytes())
        except FileNotFoundError:
            raise RepoNotFoundError(f"Repository {repo_type} {repo_id!r} not found.") from None
        return Repo(self, key, path, meta)

    def create_repo(self, repo_type: str, repo_id: str, *, author: str, private: bool = False, sdk: str | None = None) -> Repo:
        """Create a repo with one commit ("initial commit", adding ``.gitattributes``) on ``main``.

        Args:
            repo_type: ``model``, ``dataset`` or ``space``.
            repo_id: ``namespace/name``; its casing is kept for display.
            author: the account creating it (the initial commit's author).
            private: only authenticated callers see it.
            sdk: a Space's SDK.

        Returns:
            The new repo.

        Raises:
            RepoExistsError: it exists, under any casing.
            InvalidNameError: a malformed type or id.
        """
        key = self._key(repo_type, repo_id)
        final = self._repo_dir(key)
        staging = self.root / "tmp" / f"repo-{uuid.uuid4().hex}"
        with self._create_lock:
            if final.exists():
                raise RepoExistsError(f"You already created this {repo_type} repo: {repo_id}.")
            when = now()
            meta = RepoMeta(repo_type, repo_id, bool(private), format_date(when), author, sdk)
            for sub in ("commits", "blobs"):
                (staging / sub).mkdir(parents=True)
            self.write_atomic(staging / "repo.json", meta.to_json())
            repo = Repo(self, key, staging, meta)
            entry = repo.write_blob(DEFAULT_GITATTRIBUTES)
            commit = repo._new_commit({".gitattributes": entry}, (), "initial commit", "", author, when)
            repo._write_commit(commit)
            self.write_atomic(staging / "refs.json", Refs(branches={DEFAULT_BRANCH: commit.id}).to_json())
            final.parent.mkdir(parents=True, exist_ok=True)
            os.rename(staging, final)
        self._forget(key)
        return self.open(repo_type, repo_id)

    def delete_repo(self, repo_type: str, repo_id: str) -> None:
        """Delete a repo and everything in it.

        Args:
            repo_type: ``model``, ``dataset`` or ``space``.
            repo_id: ``namespace/name``.

        Raises:
            RepoNotFoundError: no such repo.
        """
        key = self._key(repo_type, repo_id)
        path = self._repo_dir(key)
        with self._create_lock, self.lock(key):
            if not (path / "repo.json").exists():
                raise RepoNotFoundError(f"Repository {repo_type} {repo_id!r} not found.")
            trash = self.root / "trash" / uuid.uuid4().hex
            os.rename(path, trash)
        self._forget(key)
        shutil.rmtree(trash, ignore_errors=True)

    def list_repos(self, repo_type: str) -> list[RepoMeta]:
        """Every repo of ``repo_type``, sorted by id.

        Args:
            repo_type: ``model``, ``dataset`` or ``space``.

        Returns:
            Their metadata; an unreadable ``repo.json`` is skipped.
        """
        base = self.root / "repos" / f"{validate_repo_type(repo_type)}s"
        metas = []
        for meta_path in base.glob("*/*/repo.json"):
            try:
                metas.append(RepoMeta.from_json(meta_path.read_bytes()))
            except (OSError, ValueError, KeyError):
                continue
        return sorted(metas, key=lambda m: m.repo_id.lower())


def _lock_exclusively(path: Path):
    """Hold an exclusive lock on ``path`` for the life of the returned file (released on exit or crash)."""
    handle = open(path, "a+")
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows: no cross-process guard
        return handle
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise StoreError(
            f"{path.parent} is in use by another hub-envs server: run one server per root, or pass another --root."
        ) from None
    return handle


class Repo:
    """One repo of a :class:`HubStore`. Get it with :meth:`HubStore.open` or :meth:`HubStore.create_repo`."""

    def __init__(self, store: HubStore, key: tuple[str, str], path: Path, meta: RepoMeta):
        self.store = store
        self.key = key
        self.path = path
        self.meta = meta

    @property
    def repo_id(self) -> str:
        return self.meta.repo_id

    @property
    def repo_type(self) -> str:
        return self.meta.repo_type

    def set_private(self, private: bool) -> None:
        """Make the repo private or public.

        Args:
            private: True for private.
        """
        with self.store.lock(self.key):
            meta = RepoMeta.from_json((self.path / "repo.json").read_bytes())
            meta.private = bool(private)
            self.store.write_atomic(self.path / "repo.json", meta.to_json())
            self.meta = meta

    # -- blobs --

    def _blob_path(self, sha256: str) -> Path:
        return self.path / "blobs" / sha256[:2] / sha256

    def write_blob(self, data: bytes) -> FileEntry:
        """Store ``data`` (once: blobs are content-addressed) and return its :class:`FileEntry`.

        Args:
            data: the file's content.
        """
        sha256 = hashlib.sha256(data).hexdigest()
        path = self._blob_path(sha256)
        if not path.exists():
            path.parent.mkdir(exist_ok=True)
            self.store.write_atomic(path, data)
        return FileEntry(oid=git_blob_oid(data), sha256=sha256, size=len(data))

    def write_blob_chunks(self, chunks: Iterable[bytes], size: int) -> FileEntry:
        """Store a blob that arrives in pieces (``size`` bytes in all), without holding it whole.

        The pieces go to a scratch file, hashed on the way; the file then moves to its address.
        Exceptions raised by ``chunks`` propagate (nothing is stored then).

        Args:
            chunks: the content's pieces, in order.
            size: the content's announced size in bytes.

        Returns:
            The blob's :class:`FileEntry`.

        Raises:
            InvalidOperationError: the pieces do not add up to ``size``.
        """
        sha256 = hashlib.sha256()
        sha1 = hashlib.sha1(b"blob %d\0" % size)
        tmp = self.store.root / "tmp" / f"{uuid.uuid4().hex}.blob"
        written = 0
        try:
            with open(tmp, "wb") as f:
                for chunk in chunks:
                    sha256.update(chunk)
                    sha1.update(chunk)
                    f.write(chunk)
                    written += len(chunk)
                if written != size:
                    raise InvalidOperationError(f"Blob size mismatch: {written} bytes received, {size} announced.")
                if self.store.fsync:
                    f.flush()
                    os.fsync(f.fileno())
            digest = sha256.hexdigest()
            path = self._blob_path(digest)
            if path.exists():
                tmp.unlink()
            else:
                path.parent.mkdir(exist_ok=True)
                os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        return FileEntry(oid=sha1.hexdigest(), sha256=digest, size=size)

    def blob_size(self, sha256: str) -> int | None:
        """The size of the blob ``sha256`` in this repo, or None if the repo does not hold it.

        Args:
            sha256: the blob's sha256 (64 lowercase hex; anything else is None).
        """
        if not re.fullmatch(r"[0-9a-f]{64}", sha256):
            return None
        try:
            return self._blob_path(sha256).stat().st_size
        except FileNotFoundError:
            return None

    def blob_entry(self, sha256: str, *, lfs: bool = False) -> FileEntry:
        """The :class:`FileEntry` of a blob already in the repo, by its sha256 (``lfs``: as an LFS file,
        whose content is never read here).

        Args:
            sha256: the blob's sha256.
            lfs: the entry of an LFS file.

        Raises:
            FileNotFoundError: the repo does not hold the blob (check :meth:`blob_size` first).
        """
        if lfs:
            return lfs_entry(sha256, self._blob_path(sha256).stat().st_size)
        data = self._blob_path(sha256).read_bytes()
        return FileEntry(oid=git_blob_oid(data), sha256=sha256, size=len(data))

    def adopt_blob(self, scratch: Path, sha256: str) -> None:
        """Move a verified scratch file (under the store's ``tmp/``, its sha256 checked by the caller) to
        its address; if the blob is there already, the scratch file is dropped.

        Args:
            scratch: the verified file.
            sha256: its sha256.
        """
        path = self._blob_path(sha256)
        if path.exists():
            scratch.unlink(missing_ok=True)
            return
        path.parent.mkdir(exist_ok=True)
        os.replace(scratch, path)

    def open_blob(self, entry: FileEntry):
        """A binary file object on the content of ``entry``.

        Args:
            entry: a file of one of this repo's commits.
        """
        return open(self._blob_path(entry.sha256), "rb")

    # -- commits --

    def _commit_path(self, sha: str) -> Path:
        return self.path / "commits" / sha[:2] / f"{sha}.json"

    def load_commit(self, sha: str) -> Commit:
        """The commit ``sha`` (40 hex); :class:`RevisionNotFoundError` if the repo has no such commit.

        Args:
            sha: the commit id.
        """
        sha = sha.lower()
        if not _HEX40.match(sha):
            raise RevisionNotFoundError(f"Invalid rev id: {sha}")

        def load() -> Commit:
            try:
                return Commit.from_json(self._commit_path(sha).read_bytes())
            except FileNotFoundError:
                raise RevisionNotFoundError(f"Invalid rev id: {sha}") from None

        return self.store.cached_commit(self.key, sha, load)

    def _write_commit(self, commit: Commit) -> None:
        path = self._commit_path(commit.id)
        if not path.exists():
            path.parent.mkdir(exist_ok=True)
            self.store.write_atomic(path, commit.to_json())

    def _new_commit(
        self,
        files: Mapping[str, FileEntry],
        parents: tuple[str, ...],
        title: str,
        message: str,
        author: str,
        when: datetime,
    ) -> Commit:
        tree = _tree_oids(files)[""]
        sha = _commit_oid(tree, parents, author, when, title, message)
        return Commit(sha, tree, parents, title, message, author, format_date(when), dict(files))

    def folder_oids(self, commit: Commit) -> dict[str, str]:
        """The git tree sha1 of every folder of ``commit`` ("" is the root).

        Args:
            commit: the commit.
        """
        return _tree_oids(commit.files)

    # -- refs --

    def refs(self) -> Refs:
        return Refs.from_json((self.path / "refs.json").read_bytes())

    def _write_refs(self, refs: Refs) -> None:
        self.store.write_atomic(self.path / "refs.json", refs.to_json())

    def resolve(self, revision: str) -> Commit:
        """The commit a branch, tag (``main``, ``refs/heads/main``, ``v1``, ``refs/tags/v1``) or 40-hex sha names.

        Args:
            revision: a branch, tag, ``refs/pr/N`` or commit id.

        Returns:
            The commit.

        Raises:
            RevisionNotFoundError: nothing of that name.
        """
        refs = self.refs()
        name = revision
        if name.startswith("refs/heads/"):
            sha = refs.branches.get(name[len("refs/heads/") :])
        elif name.startswith("refs/tags/"):
            sha = refs.tags.get(name[len("refs/tags/") :])
        elif _PR_REF.match(name):
            pr = refs.pulls.get(int(name[len("refs/pr/") :]))
            sha = pr.head if pr is not None else None
        else:
            sha = refs.branches.get(name) or refs.tags.get(name)
            if sha is None and _HEX40.match(name.lower()):
                sha = name.lower()
        if sha is None:
            raise RevisionNotFoundError(f"Invalid rev id: {revision}")
        return self.load_commit(sha)

    def create_branch(self, branch: str, start: str | None = None) -> Commit:
        """Create ``branch`` at revision ``start`` (default: ``main``).

        Args:
            branch: the new branch's name.
            start: the revision it starts at.

        Returns:
            The commit it points at.

        Raises:
            RefExistsError: the branch exists.
            InvalidNameError: not a valid branch name.
            RevisionNotFoundError: ``start`` names nothing.
        """
        validate_ref_name(branch, "branch")
        with self.store.lock(self.key):
            refs = self.refs()
            if branch in refs.branches:
                raise RefExistsError(f"Reference already exists: refs/heads/{branch}")
            commit = self.resolve(start or DEFAULT_BRANCH)
            refs.branches[branch] = commit.id
            self._write_refs(refs)
            return commit

    def delete_branch(self, branch: str) -> None:
        """Delete a branch (not ``main``).

        Args:
            branch: its name.

        Raises:
            InvalidOperationError: ``main``.
            RevisionNotFoundError: no such branch.
        """
        if branch == DEFAULT_BRANCH:
            raise InvalidOperationError(f"Cannot delete the default branch {DEFAULT_BRANCH!r}.")
        self._delete_ref(branch, tag=False)

    def _delete_ref(self, name: str, *, tag: bool) -> None:
        with self.store.lock(self.key):
            refs = self.refs()
            table = refs.tags if tag else refs.branches
            if name not in table:
                raise RevisionNotFoundError(f"Invalid rev id: {name}")
            del table[name]
            if tag:
                refs.tag_messages.pop(name, None)
            self._write_refs(refs)

    def create_tag(self, tag: str, revision: str, message: str | None = None) -> Commit:
        """Tag the commit ``revision`` names.

        Args:
            tag: the tag's name.
            revision: what it tags.
            message: the tag's message.

        Returns:
            The commit tagged.

        Raises:
            InvalidNameError: not a valid tag name.
            RefExistsError: the tag exists.
            RevisionNotFoundError: ``revision`` names nothing.
        """
        validate_ref_name(tag, "tag")
        with self.store.lock(self.key):
            refs = self.refs()
            if tag in refs.tags:
                raise RefExistsError(f"Tag already exists: refs/tags/{tag}")
            commit = self.resolve(revision)
            refs.tags[tag] = commit.id
            if message:
                refs.tag_messages[tag] = message
            self._write_refs(refs)
            return commit

    def delete_tag(self, tag: str) -> None:
        """Delete a tag.

        Args:
            tag: its name.

        Raises:
            RevisionNotFoundError: no such tag.
        """
        self._delete_ref(tag, tag=True)

    # -- history --

    def head(self, branch: str = DEFAULT_BRANCH) -> Commit:
        """The commit a branch points at.

        Args:
            branch: the branch (default ``main``).
        """
        return self.resolve(branch)

    def history(self, commit: Commit) -> Iterator[Commit]:
        """``commit`` and its first-parent ancestors, newest first.

        Args:
            commit: where the history starts.
        """
        current: Commit | None = commit
        while current is not None:
            yield current
            current = self.load_commit(current.parents[0]) if current.parents else None

    def last_commits(self, commit: Commit, paths: Sequence[str]) -> dict[str, Commit]:
        """For each path (file or folder) of ``commit``, the newest commit in its history that changed it.

        Args:
            commit: where the history starts.
            paths: files and folders of ``commit``.

        Returns:
            path -> commit, for the paths found.
        """
        remaining = set(paths)
        found: dict[str, Commit] = {}
        for current in self.history(commit):
            if not remaining:
                break
            parent_files = self.load_commit(current.parents[0]).files if current.parents else {}
            changed = {p for p in set(current.files) | set(parent_files) if current.files.get(p) != parent_files.get(p)}
            touched = set(changed)
            for p in changed:
                parts = p.split("/")
                touched.update("/".join(parts[:i]) for i in range(1, len(parts)))
            for p in list(remaining):
                if p in touched or p == "":
                    found[p] = current
                    remaining.discard(p)
        return found

    # -- committing --

    def commit(self, branch: str, change: Change) -> Commit:
        """Apply ``change`` on top of ``branch`` (an existing branch, or an open ``refs/pr/N``: tags and shas cannot
        move) and move the branch to the new commit. With ``change.parent``, the branch must still point at that
        commit, else :class:`ParentMismatchError`.

        Operations: :class:`AddFile` (its blob already written), :class:`DeleteFile`, :class:`DeleteFolder`. No
        operations make an empty commit, as git (and the Hub's commit endpoint) does.

        Args:
            branch: the branch, or an open ``refs/pr/N``.
            change: what to apply.

        Returns:
            The new commit.

        Raises:
            ParentMismatchError: ``change.parent`` is not the branch's head.
            RevisionNotFoundError: no such branch or pull request.
            InvalidOperationError: a tag, a commit id, a closed pull request, or an operation that cannot apply.
            EntryNotFoundError: a deletion of something the branch does not hold.
        """
        if not change.title:
            raise InvalidOperationError("The commit title (summary) cannot be empty.")
        with self.store.lock(self.key):
            refs = self.refs()
            pr: PullRequest | None = None
            if _PR_REF.match(branch):  # a commit to an open pull request moves refs/pr/N
                pr = refs.pulls.get(int(branch[len("refs/pr/") :]))
                if pr is None:
                    raise RevisionNotFoundError(f"Invalid rev id: {branch}")
                if pr.status != "open":
                    raise InvalidOperationError(f"Cannot commit to {branch}: the pull request is {pr.status}.")
                head_sha = pr.head
            elif branch not in refs.branches:
                if branch in refs.tags or _HEX40.match(branch.lower()):
                    raise InvalidOperationError(f"Cannot commit to {branch!r}: commits go to a branch.")
                raise RevisionNotFoundError(f"Invalid rev id: {branch}")
            else:
                head_sha = refs.branches[branch]
            if change.parent is not None and not head_sha.startswith(change.parent.lower()):
                raise ParentMismatchError("The branch was updated since you opened this page. Please refresh and try again.")
            when = now()
            commit = self._commit_on(self.load_commit(head_sha), change, branch, when)
            if pr is not None:
                event = _event("commit", change.author, when, {"subject": change.title, "oid": commit.id})
                refs.pulls[pr.num] = replace(pr, head=commit.id, events=(*pr.events, event))
            else:
                refs.branches[branch] = commit.id  # the ref moves last: a crash before this changes nothing
            self._write_refs(refs)
            return commit

    def _commit_on(self, start: Commit, change: Change, where: str, when: datetime) -> Commit:
        """Write the commit of ``change`` applied on top of ``start`` (no ref moves)."""
        files = self._apply(start.files, change.operations, where)
        if change.check is not None:
            change.check(files)
        commit = self._new_commit(files, (start.id,), change.title, change.message, change.author, when)
        self._write_commit(commit)
        return commit

    def _apply(self, start: Mapping[str, FileEntry], operations: Sequence[Operation], branch: str) -> dict[str, FileEntry]:
        """The tree ``start`` with ``operations`` applied; raises on a bad path, a missing file, a file/folder clash."""
        files = dict(start)
        for op in operations:
            validate_path(op.path)
            if isinstance(op, AddFile):
                files[op.path] = op.entry
            elif isinstance(op, DeleteFile):
                if files.pop(op.path, None) is None:
                    raise EntryNotFoundError(f"Cannot delete {op.path}: A file with this name doesn't exist on {branch!r}.")
            elif isinstance(op, DeleteFolder):
                prefix = op.path.rstrip("/") + "/"
                doomed = [p for p in files if p.startswith(prefix)]
                if not doomed:
                    raise EntryNotFoundError(f"Cannot delete folder {op.path}: no file under it on {branch!r}.")
                for p in doomed:
                    del files[p]
            else:  # pragma: no cover - programming error
                raise TypeError(f"Unknown operation {op!r}")
        clash = _file_folder_clash(files)
        if clash:
            raise InvalidOperationError(clash)
        return files

    # -- pull requests --

    def open_pull_request(self, target: str, change: Change) -> tuple[Commit, PullRequest]:
        """Open pull request ``refs/pr/<next number>`` with one commit applying ``change`` on top of the branch
        ``target`` (or of ``change.parent``, a commit of it, as the Hub does); ``target`` does not move.

        The commit object is written first, then ``refs.json`` with the new pull request: a crash in
        between leaves no pull request (an unreferenced commit is harmless).

        Args:
            target: the branch the pull request targets.
            change: its first commit.

        Returns:
            ``(commit, pull request)``.

        Raises:
            RevisionNotFoundError: ``target`` is not a branch, or ``change.parent`` names nothing.
            InvalidOperationError: an empty title, or an operation that cannot apply.
        """
        if not change.title:
            raise InvalidOperationError("The pull request title (commit summary) cannot be empty.")
        with self.store.lock(self.key):
            refs = self.refs()
            if target not in refs.branches:
                raise RevisionNotFoundError(f"Invalid rev id: {target}: a pull request targets a branch.")
            start = self.resolve(change.parent) if change.parent is not None else self.load_commit(refs.branches[target])
            when = now()
            commit = self._commit_on(start, change, target, when)
            num = max([0, *refs.pulls]) + 1
            author, title = change.author, change.title
            opening = _event(
                "comment", author, when, {"edited": False, "hidden": False, "latest": {"raw": change.message or title}}
            )
            pushed = _event("commit", author, when, {"subject": title, "oid": commit.id})
            pr = PullRequest(num, title, author, format_date(when), "open", target, start.id, commit.id, (opening, pushed))
            refs.pulls[num] = pr
            self._write_refs(refs)  # the pull request appears last
            return commit, pr

    def pull_requests(self) -> list[PullRequest]:
        """Every pull request, newest first."""
        return sorted(self.refs().pulls.values(), key=lambda pr: -pr.num)

    def pull_request(self, num: int) -> PullRequest:
        """Pull request ``num``.

        Args:
            num: its number.

        Raises:
            PullRequestNotFoundError: no such pull request.
        """
        pr = self.refs().pulls.get(int(num))
        if pr is None:
            raise PullRequestNotFoundError(f"Discussion #{num} not found in {self.repo_id}.")
        return pr

    def merge_pull_request(self, num: int, *, author: str, comment: str | None = None) -> tuple[Commit, PullRequest]:
        """Merge pull request ``num`` into its target branch: a merge commit (parents: the branch head, the
        pull request's head) whose tree is the branch with the pull request's changes applied.

        :class:`MergeConflictError` when the branch changed a file the pull request changed too since it started
        (to another content). The branch and the status move together, in one write of ``refs.json``.

        Args:
            num: the pull request's number.
            author: the account merging.
            comment: a comment added before the status change.

        Returns:
            ``(merge commit, pull request)``.

        Raises:
            PullRequestNotFoundError: no such pull request.
            InvalidOperationError: not open, or the merge would clash a file with a folder.
            MergeConflictError: both sides changed the same files (their list is in ``files``).
        """
        with self.store.lock(self.key):
            refs = self.refs()
            pr = refs.pulls.get(int(num))
            if pr is None:
                raise PullRequestNotFoundError(f"Discussion #{num} not found in {self.repo_id}.")
            if pr.status != "open":
                raise InvalidOperationError(f"Pull request #{num} is {pr.status}: only an open pull request can be merged.")
            if pr.target not in refs.branches:
                raise RevisionNotFoundError(f"Invalid rev id: {pr.target} (the target of pull request #{num})")
            ours = self.load_commit(refs.branches[pr.target])
            base, theirs = self.load_commit(pr.base), self.load_commit(pr.head)
            files = dict(ours.files)
            conflicts = []
            for path in sorted(set(base.files) | set(theirs.files)):
                was, pr_has, branch_has = base.files.get(path), theirs.files.get(path), ours.files.get(path)
                if pr_has == was:
                    continue  # the pull request did not touch it
                if branch_has != was and branch_has != pr_has:
                    conflicts.append(path)
                elif pr_has is None:
                    files.pop(path, None)
                else:
                    files[path] = pr_has
            if conflicts:
                raise MergeConflictError(
                    f"Pull request #{num} conflicts with {pr.target}: {', '.join(conflicts)} changed on both sides.", conflicts
                )
            clash = _file_folder_clash(files)
            if clash:
                raise InvalidOperationError(clash)
            when = now()
            merge = self._new_commit(files, (ours.id, theirs.id), pr.title, f"Merge pull request #{num}", author, when)
            self._write_commit(merge)
            events = [*pr.events]
            if comment:
                events.append(_event("comment", author, when, {"edited": False, "hidden": False, "latest": {"raw": comment}}))
            events.append(_event("status-change", author, when, {"status": "merged"}))
            pr = replace(pr, status="merged", merge_commit=merge.id, events=tuple(events))
            refs.pulls[pr.num] = pr
            refs.branches[pr.target] = merge.id
            self._write_refs(refs)  # the branch and the status move together
            return merge, pr

    def set_pull_request_status(self, num: int, status: str, *, author: str, comment: str | None = None) -> PullRequest:
        """Close (``closed``) or reopen (``open``) a pull request; a merged one stays merged.

        Args:
            num: the pull request's number.
            status: ``"open"`` or ``"closed"``.
            author: the account changing it.
            comment: a comment added before the status change.

        Returns:
            The pull request.

        Raises:
            PullRequestNotFoundError: no such pull request.
            InvalidOperationError: another status, or a merged pull request.
        """
        if status not in ("open", "closed"):
            raise InvalidOperationError(f"Invalid status {status!r}: expected 'open' or 'closed'.")
        with self.store.lock(self.key):
            refs = self.refs()
            pr = refs.pulls.get(int(num))
            if pr is None:
                raise PullRequestNotFoundError(f"Discussion #{num} not found in {self.repo_id}.")
            if pr.status == "merged":
                raise InvalidOperationError(f"Pull request #{num} is merged: its status cannot change.")
            when = now()
            events = [*pr.events]
            if comment:
                events.append(_event("comment", author, when, {"edited": False, "hidden": False, "latest": {"raw": comment}}))
            events.append(_event("status-change", author, when, {"status": status}))
            pr = replace(pr, status=status, events=tuple(events))
            refs.pulls[pr.num] = pr
            self._write_refs(refs)
            return pr


def _event(kind: str, author: str, when: datetime, data: dict) -> dict:
    """A discussion event as the Hub sends it (``huggingface_hub.community.deserialize_event`` reads it)."""
    return {
        "id": uuid.uuid4().hex[:24],
        "type": kind,
        "createdAt": format_date(when),
        "author": {"name": author},
        "data": data,
    }


def _file_folder_clash(files: Mapping[str, FileEntry]) -> str | None:
    """A message if some path is both a file and a folder (``a`` and ``a/b``), else None."""
    for path in files:
        parts = path.split("/")
        for i in range(1, len(parts)):
            prefix = "/".join(parts[:i])
            if prefix in files:
                return f"Cannot have both a file {prefix!r} and a file {path!r} under a folder of the same name."
    return None


def folders_of(files) -> set[str]:
    """Every folder that holds one of ``files`` (paths), at any depth: ``{"a", "a/b"}`` for ``a/b/c.txt``.

    Args:
        files: paths of files.

    >>> sorted(folders_of(["a/b/c.txt", "d.txt"]))
    ['a', 'a/b']
    """
    out: set[str] = set()
    for p in files:
        parts = p.split("/")
        out.update("/".join(parts[:i]) for i in range(1, len(parts)))
    return out
