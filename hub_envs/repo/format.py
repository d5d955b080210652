"""The env repo format: the files an env repo holds, its manifest (``hub_env.json``, :class:`Manifest`), a local env
folder (:class:`EnvFolder`), and file hashing.

Example:
    >>> from hub_envs.repo.format import Manifest, MANIFEST_FILE
    >>> MANIFEST_FILE
    'hub_env.json'
"""

from __future__ import annotations

import collections
import hashlib
import json
import os
import re
import tomllib
import types
import typing
from collections.abc import Collection
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path, PurePosixPath
from typing import Any

from hub_envs._text import safe_text
from hub_envs._version import __version__
from hub_envs.errors import ConfigError, EnvFolderError, IntegrityError, ManifestError

#: The manifest format this hub-envs writes; it reads every format from 1 up to this one.
#: 2 added ``config_overrides`` (config variants published with ``--config.<field>=<value>``); 3 ``resolved``; 4 ``tasks``
#: (a benchmark suite: several tasks in one repo), written only by a suite's push (a one-task env's manifest stays 3).
FORMAT_VERSION = 4
#: The format a suite's manifest needs (its ``tasks``); a one-task env is published as :data:`SINGLE_TASK_FORMAT_VERSION`.
SUITE_FORMAT_VERSION = 4
SINGLE_TASK_FORMAT_VERSION = 3
MANIFEST_FILE = "hub_env.json"
CARD_FILE = "README.md"
ENV_ENTRY_FILE = "env.py"
PROJECT_FILE = "pyproject.toml"
DATASET_DIR = "dataset"
MEDIA_DIR = "media"
GIF_FILE = f"{MEDIA_DIR}/rollout.gif"
MP4_FILE = f"{MEDIA_DIR}/rollout.mp4"

#: Files push_env generates; an env folder must not contain them (they would be overwritten).
GENERATED = (MANIFEST_FILE, CARD_FILE, ENV_ENTRY_FILE, DATASET_DIR, MEDIA_DIR)
#: Files the Hub itself may add to a repo; never part of the env.
HUB_FILES = (".gitattributes",)
#: Where reproduction attestations (:mod:`hub_envs.repo.attestations`) land once the repo's owner merges their pull request.
REPRODUCTIONS_DIR = "reproductions"
#: An attestation (``reproductions/<name>.json``) or its OpenSSH signature (``.json.sig``): one plain file name, data only.
_ATTESTATION_PATH_RE = re.compile(r"^reproductions/[A-Za-z0-9][A-Za-z0-9._-]{0,200}\.json(\.sig)?$")
#: Left out of an env folder when publishing.
IGNORED_PARTS = ("__pycache__", ".git", ".ipynb_checkpoints", ".pytest_cache", ".venv")
IGNORED_SUFFIXES = (".pyc", ".pyo")

_SHA256_RE = re.compile(r"^[0-9a-f]{64}$")
_REPUBLISH = "Re-publish with push_env, which writes a valid manifest."
_SHA1_RE = re.compile(r"^[0-9a-f]{40}$")


def is_commit_sha(revision: str | None) -> bool:
    """Whether ``revision`` is a full 40-hex commit id (the only revision that pins content).

    Args:
        revision: a revision, or None.

    Returns:
        True for a commit sha.
    """
    return bool(revision) and bool(_SHA1_RE.match(revision))


#: Files Python can import as code: source, and compiled extension modules (``x.so``, ``x.abi3.so``,
#: ``x.cpython-311-x86_64-linux-gnu.so``, ``x.pyd``), which the import system would pick before ``x.py``.
CODE_SUFFIXES = (".py", ".so", ".pyd")
#: ``module:Attr`` (dotted parts allowed on both sides).
ENTRY_POINT_RE = re.compile(r"^(?P<module>[A-Za-z_]\w*(\.[A-Za-z_]\w*)*):(?P<attr>[A-Za-z_]\w*(\.[A-Za-z_]\w*)*)$")
#: What gymnasium accepts as the id part we prefix to ``-<sha>`` (namespace/name, no spaces).
GYM_ID_RE = re.compile(r"^(?:[\w:.-]+/)?[\w:.-]+$")


def is_lazy_file(path: str) -> bool:
    """A file ``load_env`` does not fetch: the dataset's data (``dataset/data/``, ``dataset/videos/``,
    anything under ``dataset/`` but its ``meta/``). It is fetched, and verified against the manifest,
    when the dataset is opened (:meth:`hub_envs.loading.loaded.LoadedEnv.fetch_dataset`). Never code: a ``.py``
    (or anything Python could run) under ``dataset/`` is fetched and verified with the rest of the code.

    >>> [is_lazy_file(p) for p in ("dataset/data/chunk-000/file-000.parquet", "dataset/meta/info.json", "env.py")]
    [True, False, False]
    >>> is_lazy_file("dataset/helper.py"), is_lazy_file("dataset/data/x.so")
    (False, False)
    """
    return (
        path.startswith(DATASET_DIR + "/")
        and not path.startswith(DATASET_DIR + "/meta/")
        and not is_code_file(path)
        and not path.endswith(EXECUTABLE_SUFFIXES)
    )


def is_media_file(path: str) -> bool:
    """The card's media (``media/rollout.gif``, ``media/rollout.mp4``): only the card and the web page show them,
    so ``load_env`` does not fetch them (:meth:`hub_envs.loading.loaded.LoadedEnv.media_file` does, verified). Never code.

    >>> is_media_file("media/rollout.mp4"), is_media_file("media/helper.py"), is_media_file("README.md")
    (True, False, False)
    """
    return path.startswith(MEDIA_DIR + "/") and not is_code_file(path) and not path.endswith(EXECUTABLE_SUFFIXES)


def is_on_demand_file(path: str) -> bool:
    """Whether ``load_env`` leaves a file on the Hub until something needs it: the dataset's data (:func:`is_lazy_file`)
    and the card's media (:func:`is_media_file`).

    Args:
        path: a repo path.

    Returns:
        True for such a file.
    """
    return is_lazy_file(path) or is_media_file(path)


def is_attestation_file(path: str) -> bool:
    """A reproduction attestation merged through a pull request, or its signature: ``reproductions/<name>.json``
    and ``reproductions/<name>.json.sig`` (one plain file name, no sub-folder; never code).

    >>> [is_attestation_file(p) for p in ("reproductions/2026-01-02-0123456789ab.json", "reproductions/a.json.sig")]
    [True, True]
    >>> [is_attestation_file(p) for p in ("reproductions/x.py", "reproductions/a/b.json", "reproductions/.json")]
    [False, False, False]
    """
    return bool(_ATTESTATION_PATH_RE.match(path))


def beyond_manifest(path: str) -> bool:
    """Whether a commit of an env repo may hold ``path`` although its manifest does not list it: the ONE rule
    hub-envs' readers and writers of env repos follow (load_env's snapshot checks and lazy fetch, and push_env,
    which keeps such files; the generated ``env.py``, which cannot import hub-envs, refuses unlisted code only).

    These are the files the Hub workflow adds after push_env published the commit: the manifest itself, the Hub's
    ``.gitattributes``, and the reproduction attestations the owner merges from pull requests
    (:func:`is_attestation_file`). A refreshed card is not among them: push_env's card-only commit lists the new
    card's hash in the manifest, so it is verified like every other file. Anything else unlisted (code above all)
    is refused. A load neither fetches these files nor hashes them into the content digest, so the commit's
    content, its content tag and the consent given to it are the same with or without them.

    >>> [beyond_manifest(p) for p in ("hub_env.json", ".gitattributes", "reproductions/2026-01-02-0123456789ab.json")]
    [True, True, True]
    >>> [beyond_manifest(p) for p in ("README.md", "reproductions/evil.py", "notes.json")]
    [False, False, False]
    """
    return path == MANIFEST_FILE or path in HUB_FILES or is_attestation_file(path)


def is_code_file(path: str) -> bool:
    """Whether a repo path is code: what the trust prompt lists.

    Args:
        path: a repo path.

    Returns:
        True for ``.py`` files and ``pyproject.toml``.
    """
    return path.endswith(CODE_SUFFIXES)


#: Compiled Python an env repo never holds: bytecode, which Python runs instead of the ``.py`` beside it.
BYTECODE_SUFFIXES = (".pyc", ".pyo")
#: Compiled files push_env refuses to publish from an env folder (hub-envs imports ``.py`` sources only).
COMPILED_SUFFIXES = (".pyc", ".pyo", ".so", ".pyd")


def is_bytecode_path(path: str) -> bool:
    """Whether a repo path is bytecode: ``.pyc``/``.pyo`` files and anything under a ``__pycache__/`` folder.

    Args:
        path: a repo path.

    Returns:
        True for bytecode.
    """
    return path.endswith(BYTECODE_SUFFIXES) or "__pycache__" in PurePosixPath(path).parts


# --- paths and hashing ------------------------------------------------------------------------


#: What a repo path may not contain: C0 controls, DEL, C1 controls (8-bit CSI/OSC...), Unicode line and
#: paragraph separators, bidirectional overrides/isolates/marks (they reorder what a terminal shows) and
#: lone surrogates (a non-UTF-8 file name read with surrogateescape). A fixed list, so both stacks agree.
_UNSAFE_PATH_RE = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u200e\u200f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff]")
#: The longest file or folder name (one path component) common file systems accept, in UTF-8 bytes.
MAX_NAME_BYTES = 255


def safe_relpath(path: str, *, where: str) -> str:
    """A path of a manifest, checked to stay inside the repo.

    Args:
        path: a repo path as a manifest lists it.
        where: names the manifest in messages.

    Returns:
        ``path`` as a normalized POSIX path.

    Raises:
        ManifestError: a path that could escape the repo, holds control or bidi-override characters, or has a component
            longer than file systems allow.
    """
    if not isinstance(path, str) or not path or "\x00" in path or "\\" in path:
        raise ManifestError(f"{where}: {path!r} is not a valid repo path. Use forward-slash paths relative to the repo root.")
    p = PurePosixPath(path)
    if p.is_absolute() or any(part in ("..", "") for part in p.parts) or path.startswith("./") or path != str(p):
        raise ManifestError(
            f"{where}: path {path!r} is absolute or escapes the repo. Only plain relative paths such as "
            f"'physics.py' or 'assets/robot.urdf' are allowed."
        )
    if _UNSAFE_PATH_RE.search(path):
        raise ManifestError(
            f"{where}: path '{safe_text(path)}' contains control or bidirectional-override characters (shown escaped), "
            f"which can disguise a file name on a terminal. Rename the file to plain printable characters and re-publish "
            f"with push_env."
        )
    for part in p.parts:
        if len(part.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
            raise ManifestError(
                f"{where}: path '{safe_text(path[:80])}...' has a name longer than {MAX_NAME_BYTES} bytes, which file systems "
                f"refuse. Shorten the file or folder name and re-publish with push_env."
            )
    return path


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """The sha256 of a file.

    Args:
        path: the file.
        chunk: bytes read at a time.

    Returns:
        64 hex digits.
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def _ignored(rel: PurePosixPath) -> bool:
    return any(part in IGNORED_PARTS for part in rel.parts) or rel.name.endswith(IGNORED_SUFFIXES)


#: Files Python would import or load instead of (or besides) a verified ``.py`` source.
EXECUTABLE_SUFFIXES = (".py", ".pyc", ".pyo", ".so", ".pyd")


def executable_files(root: Path) -> list[str]:
    """Every file under a folder Python could run, caches included (``__pycache__/*.pyc``, ``*.so``).

    Args:
        root: a folder.

    Returns:
        Their relative POSIX paths, sorted.
    """
    root = Path(root)
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in filenames:
            if name.endswith(EXECUTABLE_SUFFIXES):
                out.append(Path(dirpath, name).relative_to(root).as_posix())
    return sorted(out)


def list_files(root: Path, *, skip: tuple[str, ...] = ()) -> list[str]:
    """The files of a folder a push publishes.

    Args:
        root: a folder.
        skip: relative paths to leave out too.

    Returns:
        Relative POSIX paths, sorted; caches (:data:`IGNORED_PARTS`) and the Hub's own files left out.
    """
    root = Path(root)
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in IGNORED_PARTS)
        for name in filenames:
            rel = PurePosixPath(Path(dirpath, name).relative_to(root).as_posix())
            if _ignored(rel) or str(rel) in skip or str(rel) in HUB_FILES:
                continue
            out.append(str(rel))
    return sorted(out)


def check_publishable(root: Path) -> None:
    """Refuse to publish an env folder holding what must never reach the Hub.

    * a symlink (to a file or a folder) whose target lies outside ``root``, or does not exist: publishing follows links,
      so ``assets/calibration.yaml -> ~/.ssh/id_ed25519`` would upload the key. Symlinks to files inside the folder are
      fine (their target's contents are published);
    * compiled files (``.pyc``, ``.pyo``, ``.so``, ``.pyd``): hub-envs imports ``.py`` sources only, and the manifest
      must list only what a reader can check.

    ``__pycache__/`` folders (written by your own Python) and the other :data:`IGNORED_PARTS` are skipped silently: they
    are never published.

    Args:
        root: the env folder.

    Raises:
        EnvFolderError: naming every offending file (and each link's target) and what to do.
    """
    root = Path(root).absolute()
    real_root = root.resolve()
    links: list[str] = []
    compiled: list[str] = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in IGNORED_PARTS)
        for name in sorted(dirnames) + sorted(filenames):
            path = Path(dirpath, name)
            rel = path.relative_to(root).as_posix()
            if path.is_symlink():
                target = Path(os.path.realpath(path))
                if not target.exists():
                    links.append(f"  {safe_text(rel)} -> {safe_text(os.readlink(path))} (the target does not exist)")
                    continue
                if target != real_root and real_root not in target.parents:
                    links.append(
                        f"  {safe_text(rel)} -> {safe_text(target)} (outside the env folder; its contents would be published)"
                    )
                    continue
            if name in filenames and name.endswith(COMPILED_SUFFIXES):
                compiled.append(f"  {safe_text(rel)}")
    problems = []
    if links:
        problems.append(
            "symlinks that lead outside the folder (nothing was published):\n"
            + "\n".join(links)
            + "\nIf a file belongs to the env, copy it into the folder in place of the link; otherwise remove the link."
        )
    if compiled:
        problems.append(
            "compiled files, which hub-envs never publishes or imports (it runs .py sources only):\n"
            + "\n".join(compiled)
            + "\nDelete them (ship the .py source instead); __pycache__/ folders are skipped by themselves."
        )
    if problems:
        raise EnvFolderError(f"Cannot publish the env folder {safe_text(root)}: " + "\n".join(problems))


def hash_files(root: Path, paths: list[str]) -> dict[str, str]:
    """The sha256 of files of a folder.

    Args:
        root: the folder.
        paths: relative paths.

    Returns:
        ``{path: sha256}``, sorted.
    """
    return {p: sha256_file(Path(root, p)) for p in sorted(paths)}


def content_digest(files: dict[str, str]) -> str:
    """The identity of a repo's content: one sha256 over its (path, sha256) pairs, card and manifest excluded (the card names
    this digest: a commit cannot name its own sha).

    Args:
        files: ``{path: sha256}``.

    Returns:
        64 hex digits.
    """
    h = hashlib.sha256()
    for path in sorted(files):
        if path in (CARD_FILE, MANIFEST_FILE):
            continue
        h.update(f"{path}\x00{files[path]}\n".encode())
    return h.hexdigest()


def code_digest(files: dict[str, str]) -> str:
    """The digest of the env's code alone (all files but dataset, media, card and manifest): what the dataset's
    ``env_meta.code_digest`` names, since the dataset cannot name the commit it is part of.

    Args:
        files: ``{path: sha256}``.

    Returns:
        64 hex digits.
    """
    return content_digest(
        {p: h for p, h in files.items() if not p.startswith(f"{DATASET_DIR}/") and not p.startswith(f"{MEDIA_DIR}/")}
    )


def content_tag(digest: str) -> str:
    """The tag push_env puts on every commit it makes: content-addressed, so a card can pin it.

    Args:
        digest: a content digest.

    Returns:
        ``sha256-<first 16 hex digits>``.
    """
    return f"sha256-{digest[:16]}"


# --- the manifest -----------------------------------------------------------------------------

#: What a Hub repo id is, said in every error that refuses one.
REPO_ID_RULE = (
    "a Hub repo id is 'user/name': ASCII letters, digits, '-', '_' and '.' on each side of one '/' and nothing else "
    "(no spaces, newlines or control characters); neither part starts or ends with '-' or '.' or holds '--' or '..'"
)
_NOT_REPO_ID_CHAR = re.compile(r"[^\w./-]", re.ASCII)  # searched in the whole text: "user/name\n" has one
#: One side of a repo id, as huggingface_hub's ``validate_repo_id`` (1.x, the stricter) takes it: checked here, not by
#: importing it (its module imports the client's HTTP stack, a good part of a cached load's time);
#: ``tests/test_first_step.py`` holds the two to the same verdicts.
_REPO_ID_PART = re.compile(r"\b[\w.-]{1,96}\b", re.ASCII)


def repo_id_problem(value: object) -> str | None:
    """Why ``value`` is not a Hub repo id (``user/name``), or None when it is one: the one rule of every entry that
    takes a repo id (``load_env``, ``push_env``, ``trust``, the commands' flags, a manifest's ``repo_id``...).

    huggingface_hub's own rules (``validate_repo_id``: 1 to 96 characters a side, no ``--``, ``..`` or trailing ``.git``)
    are applied too, matched to the end of the text (0.35's pattern ends in ``$``, which lets ``"user/name\\n"`` through).

    >>> repo_id_problem("user/pendulum-lerobot") is None
    True
    >>> repo_id_problem("user/name\\n")
    "it holds a character that is not an ASCII letter, digit, '-', '_' or '.'"
    >>> repo_id_problem("name")
    "it needs a namespace: 'user/name'"
    """
    if not isinstance(value, str):
        return f"it is a {type(value).__name__}, not text"
    if not value:
        return "it is empty"
    if _NOT_REPO_ID_CHAR.search(value):
        return "it holds a character that is not an ASCII letter, digit, '-', '_' or '.'"
    if "/" not in value:
        return f"it needs a namespace: 'user/{value}'"
    if value.count("/") != 1:
        return "it has more than one '/'"
    for part in value.split("/"):
        if not _REPO_ID_PART.fullmatch(part):
            return (
                f"{part!r} is not 1 to 96 ASCII letters, digits, '-', '_' or '.' that start and end with a letter, digit or '_'"
            )
    if "--" in value or ".." in value:
        return "it holds '--' or '..'"
    if value.endswith(".git"):
        return "it ends in '.git'"
    return None


def _namespace(name: str) -> str | None:
    """The ``namespace`` of ``namespace/rest`` (a repo id, gym id or draccus choice), or None."""
    return name.split("/", 1)[0] if "/" in name else None


def _check_namespaces(repo_id: str, gym_id: str, env_type: str, *, where: str, what: str) -> None:
    owner = _namespace(repo_id)
    for key, value in (("gym_id", gym_id), ("env_type", env_type)):
        ns = _namespace(value)
        if ns is None or owner is None or ns.casefold() != owner.casefold():
            claimed = f"namespace '{safe_text(ns)}'" if ns is not None else "no namespace"
            raise ManifestError(
                f"{where}: {key} '{safe_text(value)}' ({claimed}) is not under the namespace of {what} "
                f"'{safe_text(repo_id)}' ('{safe_text(owner)}'): load_env registers {key} under that name, so a repo could "
                f"pass its env off as another user's. Do not load it; its publisher must re-publish with push_env, which "
                f"names the env after the repo ({key} = '{safe_text(repo_id)}')."
            )


def check_names_belong_to(manifest: Manifest, repo_id: str) -> None:
    """Refuse a manifest downloaded from the Hub repo ``repo_id`` if a name it registers or claims is under another
    namespace: its ``gym_id``, ``env_type`` (what load_env registers with gymnasium and draccus) and ``repo_id`` must all
    be in ``repo_id``'s namespace (case-insensitively, as on the Hub).

    ``Manifest.from_dict`` checks the manifest against its own ``repo_id`` field, which the publisher writes; this checks
    it against the repo it was actually downloaded from (load_env calls it right after reading a Hub snapshot's
    manifest, before the trust gate).

    Args:
        manifest: the manifest read.
        repo_id: the repo it was downloaded from.

    Raises:
        ManifestError: naming both the claimed and the actual namespace.
    """
    where = f"{safe_text(repo_id)}: {MANIFEST_FILE}"
    if manifest.repo_id is not None and (_namespace(manifest.repo_id) or "").casefold() != (_namespace(repo_id) or "").casefold():
        raise ManifestError(
            f"{where}: repo_id '{safe_text(manifest.repo_id)}' is under namespace '{safe_text(_namespace(manifest.repo_id))}', "
            f"but the manifest was downloaded from '{safe_text(repo_id)}' (namespace '{safe_text(_namespace(repo_id))}'): "
            f"it claims to be another user's env. Do not load it; its publisher must re-publish with push_env."
        )
    _check_namespaces(repo_id, manifest.gym_id, manifest.env_type, where=where, what="the repo it was downloaded from")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check_fingerprint_and_seeds(data: dict, where: str) -> None:
    """The fields load_env computes with must have the shapes push_env writes."""
    fp = data.get("fingerprint") or {}
    if fp:
        seeds, episodes = fp.get("seeds"), fp.get("episodes")
        if not (isinstance(seeds, list) and seeds and all(_is_int(x) and x >= 0 for x in seeds)):
            raise ManifestError(f"{where}: fingerprint.seeds must be a non-empty list of non-negative ints. {_REPUBLISH}")
        if not (_is_int(fp.get("steps")) and fp["steps"] > 0):
            raise ManifestError(f"{where}: fingerprint.steps must be a positive int. {_REPUBLISH}")
        if not (isinstance(fp.get("digest"), str) and _SHA256_RE.match(fp["digest"])):
            raise ManifestError(f"{where}: fingerprint.digest must be a sha256 hex digest. {_REPUBLISH}")
        if not (
            isinstance(episodes, list)
            and len(episodes) == len(seeds)
            and all(isinstance(e, str) and _SHA256_RE.match(e) for e in episodes)
        ):
            raise ManifestError(f"{where}: fingerprint.episodes must hold one sha256 per seed. {_REPUBLISH}")
    seeds = data.get("seeds") or {}
    if "check" in seeds and not (_is_int(seeds["check"]) and seeds["check"] >= 0):
        raise ManifestError(f"{where}: seeds.check must be a non-negative int, got {seeds['check']!r}. {_REPUBLISH}")


def _json_kind(annotation: Any) -> tuple[type, ...]:
    """The JSON value types a manifest field of this (resolved) annotation may hold."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        return tuple(k for arg in typing.get_args(annotation) for k in _json_kind(arg))
    base = origin or annotation
    if base is type(None):
        return (type(None),)
    return {str: (str,), int: (int,), dict: (dict,), tuple: (list,), list: (list,)}.get(base, (object,))


def _check_field_types(cls: type, data: dict, where: str) -> None:
    """Unknown, missing and mistyped fields, driven by the dataclass's own fields and annotations."""
    hints = typing.get_type_hints(cls)
    version = data["format_version"]
    known = {f.name: f for f in fields(cls) if f.metadata.get("since", 1) <= version}
    unknown = sorted(set(data) - set(known))
    if unknown:
        writer = data.get("versions", {}).get("hub-envs") if isinstance(data.get("versions"), dict) else None
        by = f"hub-envs {safe_text(str(writer))}" if writer else "an unknown writer"
        raise ManifestError(
            f"{where}: unknown field(s) {[safe_text(u) for u in unknown]} for format_version {version} (written by "
            f"{by}). Fields are only ever added with a new format_version, so this manifest was edited by hand or "
            f"written by a hub-envs that did not follow the format. {_REPUBLISH}"
        )
    missing = [name for name, f in known.items() if f.default is MISSING and f.default_factory is MISSING and name not in data]
    if missing:
        raise ManifestError(f"{where}: missing field(s) {missing}. Re-publish with push_env, which writes them all.")
    for name, value in data.items():
        kinds = _json_kind(hints[name])
        ok = isinstance(value, kinds) and not (isinstance(value, bool) and bool not in kinds and int in kinds)
        if not ok:
            wanted = _FIELD_SHAPES.get(name) or " or ".join(_JSON_NAMES.get(k, k.__name__) for k in kinds)
            raise ManifestError(f"{where}: field {name!r} must be {wanted}, got {type(value).__name__}. {_REPUBLISH}")


#: What to tell an author about a field whose type is wrong, where the type name alone says too little.
_FIELD_SHAPES = {"requirements": "a list of requirement strings such as 'pybullet>=3.2'"}
_JSON_NAMES = {str: "a string", int: "an integer", dict: "an object", list: "a list", type(None): "null"}


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_benchmark(entry: dict, where: str) -> None:
    """A ``benchmarks`` entry (what push_env writes and ``hub-envs reproduce`` re-runs), checked before it is used."""
    name, policy, episodes = entry.get("name"), entry.get("policy"), entry.get("episodes")
    if not (isinstance(name, str) and name):
        raise ManifestError(f"{where}: 'name' must be a non-empty string. {_REPUBLISH}")
    if not (isinstance(policy, dict) and isinstance(policy.get("type"), str)):
        raise ManifestError(f"{where}: 'policy' must be an object with a string 'type' (e.g. \"random\"). {_REPUBLISH}")
    if not (_is_int(episodes) and episodes > 0):
        raise ManifestError(f"{where}: 'episodes' must be a positive int. {_REPUBLISH}")
    seeds = entry.get("seeds")
    if not (isinstance(seeds, list) and len(seeds) == episodes and all(_is_int(x) and x >= 0 for x in seeds)):
        raise ManifestError(f"{where}: 'seeds' must list one non-negative int per episode ({episodes}). {_REPUBLISH}")
    metrics = entry.get("metrics")
    if not (isinstance(metrics, dict) and metrics and all(isinstance(k, str) and _is_number(v) for k, v in metrics.items())):
        raise ManifestError(f"{where}: 'metrics' must map metric names to numbers. {_REPUBLISH}")
    tolerance = entry.get("tolerance", {})
    if not (isinstance(tolerance, dict) and all(k in metrics and _is_number(v) and v >= 0 for k, v in tolerance.items())):
        raise ManifestError(f"{where}: 'tolerance' must map metrics it names to non-negative numbers. {_REPUBLISH}")
    per_episode = entry.get("per_episode", {})
    if not (isinstance(per_episode, dict) and all(isinstance(v, list) and len(v) == episodes for v in per_episode.values())):
        raise ManifestError(f"{where}: 'per_episode' must map names to lists of one value per episode. {_REPUBLISH}")
    if "max_steps" in entry and not (_is_int(entry["max_steps"]) and entry["max_steps"] > 0):
        raise ManifestError(f"{where}: 'max_steps' must be a positive int. {_REPUBLISH}")


def _check_tasks(data: dict, where: str) -> None:
    """A suite's ``tasks`` (format 4): distinct task names, each with its task_index, episodes, seeds and fingerprint."""
    tasks = data.get("tasks", [])
    if not isinstance(tasks, list) or not all(isinstance(t, dict) for t in tasks):
        raise ManifestError(f"{where}: 'tasks' must be a list of objects. {_REPUBLISH}")
    names = [t.get("task") for t in tasks]
    if not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
        raise ManifestError(
            f"{where}: 'tasks' must name distinct tasks (non-empty strings), got {safe_text(repr(names))[:200]}. {_REPUBLISH}"
        )
    bad = [n for n in names if not _TASK_RE.match(n) or n != n.strip()]  # the rule push_env holds pyproject's tasks to
    if bad:  # a manifest written by hand must not bring escape sequences or line breaks to a terminal, a card or a report
        raise ManifestError(
            f"{where}: 'tasks' names {safe_text(repr(bad[0])[:80])}: a task name is one line of 1 to 200 printable "
            f"characters, without commas or surrounding spaces (as [tool.hub-envs] tasks). {_REPUBLISH}"
        )
    for i, t in enumerate(tasks):
        episodes, seeds = t.get("episodes"), t.get("seeds")
        if not (
            t.get("task_index") == i
            and isinstance(t.get("instruction"), str)
            and isinstance(episodes, list)
            and all(_is_int(e) and e >= 0 for e in episodes)
            and isinstance(seeds, list)
            and len(seeds) == len(episodes)
            and all(_is_int(s) and s >= 0 for s in seeds)
            and isinstance(t.get("fingerprint", {}), dict)
        ):
            raise ManifestError(
                f"{where}: tasks[{i}] ({safe_text(str(names[i]))}) must hold task_index {i}, a string instruction, and "
                f"its dataset episodes and their seeds (lists of non-negative ints of one length). {_REPUBLISH}"
            )


def _newer_format_message(data: dict, version: int, where: str) -> str:
    """A manifest from a newer hub-envs: name the version that wrote it, and the upgrade that reads it."""
    versions = data.get("versions")
    writer = versions.get("hub-envs") if isinstance(versions, dict) and isinstance(versions.get("hub-envs"), str) else None
    by = f"hub-envs {safe_text(writer)}" if writer else "a newer hub-envs"
    pin = f"'hub-envs>={writer}'" if writer and re.fullmatch(r"[0-9][0-9A-Za-z.+-]*", writer) else "hub-envs"
    return (
        f"{where}: format_version {version} was written by {by}; this hub-envs ({__version__}) reads format_version "
        f"{FORMAT_VERSION} and older. To read it, upgrade hub-envs: pip install -U {pin}"
    )


_TASK_INDEXES: dict[int, tuple[tuple, dict[str, dict[str, Any]]]] = {}  # id(tasks) -> (tasks, index), the last few


def _task_index(tasks: tuple[dict[str, Any], ...]) -> dict[str, dict[str, Any]]:
    """A suite's task records by task name, made once per ``tasks`` tuple (a suite of thousands of tasks looks each one
    up once per task); kept outside the manifest, which stays a plain frozen dataclass of its fields."""
    hit = _TASK_INDEXES.get(id(tasks))
    if hit is not None and hit[0] is tasks:  # the same tuple, not a new one at a reused address
        return hit[1]
    index = {str(record["task"]): record for record in tasks}
    if len(_TASK_INDEXES) >= 8:
        _TASK_INDEXES.clear()  # one call: safe beside another thread's lookup
    _TASK_INDEXES[id(tasks)] = (tasks, index)
    return index


@dataclass(frozen=True)
class Manifest:
    """What ``hub_env.json`` holds. Frozen: load, check, never mutate.

    Everything in it can be read without trusting the repo's code.
    """

    name: str
    env_entry_point: str
    config_entry_point: str
    gym_id: str
    env_type: str
    files: dict[str, str]
    content_digest: str
    format_version: int = SINGLE_TASK_FORMAT_VERSION  # a suite's push writes SUITE_FORMAT_VERSION
    repo_id: str | None = None
    version: str = "0.0.0"
    description: str = ""
    code_digest: str = ""  # digest of the code files alone (what the dataset's env_meta names)
    requirements: tuple[str, ...] = ()
    config: dict[str, Any] = field(default_factory=dict)
    dataset: dict[str, Any] = field(default_factory=dict)
    fingerprint: dict[str, Any] = field(default_factory=dict)
    seeds: dict[str, Any] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    benchmarks: tuple[dict[str, Any], ...] = ()
    processors: tuple[dict[str, Any], ...] = ()
    #: the config fields the publisher set (``push_env --config.<field>=<value>``); the rest are the code's
    #: defaults. ``config`` holds every resulting value, which load_env checks the code still computes.
    config_overrides: dict[str, Any] = field(default_factory=dict, metadata={"since": 2})
    #: the installed version of every package in the closure of ``requirements`` (numpy and gymnasium
    #: included) when push_env ran: ``versions="publisher"`` pins them all, not only the requirements.
    resolved: dict[str, str] = field(default_factory=dict, metadata={"since": 3})
    #: a benchmark suite's tasks, in task-id order: ``task`` (the config's ``task`` value), ``task_index`` (its
    #: ``task_index`` in the dataset), ``instruction`` (its language instruction in ``meta/tasks.parquet``), its dataset
    #: ``episodes`` and their ``seeds``, its golden-rollout ``fingerprint``. Empty: a one-task env.
    tasks: tuple[dict[str, Any], ...] = field(default=(), metadata={"since": 4})

    # -- (de)serialization --

    def validated(self, *, where: str = MANIFEST_FILE) -> Manifest:
        """This manifest checked as every reader checks it, so what push_env publishes is what load_env accepts.

        Args:
            where: names it in messages.

        Returns:
            The manifest, read back from its own dict.

        Raises:
            ManifestError: a field that is not what the format allows.
        """
        return type(self).from_dict(self.to_dict(), where=where)

    def to_dict(self) -> dict[str, Any]:
        """The manifest as JSON-ready data, with only the fields of its ``format_version``."""
        d = {k: v for k, v in asdict(self).items() if _FIELD_SINCE.get(k, 1) <= self.format_version}
        d["requirements"] = list(self.requirements)
        d["benchmarks"] = list(self.benchmarks)
        d["processors"] = list(self.processors)
        if "tasks" in d:
            d["tasks"] = list(self.tasks)
        return d

    def to_json(self) -> str:
        """Canonical JSON: sorted keys, fixed indentation, so identical content gives identical bytes."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True, allow_nan=False) + "\n"

    @classmethod
    def from_dict(cls, data: Any, *, where: str = MANIFEST_FILE) -> Manifest:
        """Read and check a manifest of any format this hub-envs reads (a field added later gets its default).

        Args:
            data: the decoded ``hub_env.json``.
            where: names it in messages.

        Returns:
            The :class:`Manifest`.

        Raises:
            ManifestError: a newer format (naming the hub-envs that reads it), an unknown field, or a field of the wrong type
                or value.
        """
        if not isinstance(data, dict):
            raise ManifestError(
                f"{where}: the manifest must be a JSON object, got {type(data).__name__}. Re-publish with push_env."
            )
        version = data.get("format_version")
        if type(version) is int and version > FORMAT_VERSION:
            raise ManifestError(_newer_format_message(data, version, where))
        if type(version) is not int or not 1 <= version <= FORMAT_VERSION:
            raise ManifestError(
                f"{where}: format_version {version!r} is not supported (this hub-envs reads 1 to {FORMAT_VERSION}); "
                f"re-publish it with push_env."
            )
        _check_field_types(cls, data, where)
        for key in ("env_entry_point", "config_entry_point"):
            if not ENTRY_POINT_RE.match(data[key]):
                raise ManifestError(
                    f"{where}: {key} {data[key]!r} is not of the form 'module:Attribute' "
                    f"(e.g. 'pendulum_env:PendulumEnv'). {_REPUBLISH}"
                )
        for key in ("gym_id", "env_type"):
            if not GYM_ID_RE.match(data[key]):
                raise ManifestError(
                    f"{where}: {key} {data[key]!r} is not a valid name (letters, digits, '_', '-', '.', "
                    f"':' and one optional 'namespace/'). {_REPUBLISH}"
                )
        repo_id = data.get("repo_id")
        problem = repo_id_problem(repo_id) if repo_id is not None else None
        if problem is not None:
            raise ManifestError(f"{where}: repo_id {repo_id!r} is not valid: {problem}; {REPO_ID_RULE}. {_REPUBLISH}")
        if repo_id is not None:
            _check_namespaces(repo_id, data["gym_id"], data["env_type"], where=where, what="its own repo_id")
        if "path" in data.get("dataset", {}):
            safe_relpath(data["dataset"]["path"], where=f"{where} dataset.path")
        record = data.get("dataset", {}).get("dataset_repo", {})  # the dataset repo commit holding the same dataset
        if not isinstance(record, dict) or (
            record and not (repo_id_problem(record.get("repo_id")) is None and is_commit_sha(record.get("revision")))
        ):
            raise ManifestError(
                f"{where}: dataset.dataset_repo {safe_text(repr(record))[:200]} must name a dataset repo ('user/name') and a "
                f"commit sha. {_REPUBLISH}"
            )
        files = data["files"]
        if not isinstance(files, dict) or not files:
            raise ManifestError(f"{where}: field 'files' must map each repo path to its sha256. {_REPUBLISH}")
        for path, digest in files.items():
            safe_relpath(path, where=f"{where} files")
            if is_bytecode_path(path):
                raise ManifestError(
                    f"{where}: files lists compiled bytecode '{safe_text(path)}'. Python would run it instead of the source "
                    f"the manifest shows, so an env repo must hold .py sources only: delete the __pycache__ folders and "
                    f".pyc/.pyo files and re-publish with push_env (which never publishes them)."
                )
            if not isinstance(digest, str) or not _SHA256_RE.match(digest):
                raise ManifestError(f"{where}: files[{path!r}] = {digest!r} is not a sha256 hex digest. {_REPUBLISH}")
        if not _SHA256_RE.match(data["content_digest"]):
            raise ManifestError(f"{where}: content_digest {data['content_digest']!r} is not a sha256 hex digest. {_REPUBLISH}")
        reqs = data.get("requirements", [])
        if not all(isinstance(r, str) for r in reqs):
            raise ManifestError(
                f"{where}: 'requirements' must be a list of requirement strings such as 'pybullet>=3.2'. {_REPUBLISH}"
            )
        _check_fingerprint_and_seeds(data, where)
        for key in ("benchmarks", "processors"):
            val = data.get(key, [])
            if not isinstance(val, list) or not all(isinstance(v, dict) for v in val):
                raise ManifestError(f"{where}: {key!r} must be a list of objects. {_REPUBLISH}")
        for i, entry in enumerate(data.get("benchmarks", [])):
            _check_benchmark(entry, f"{where} benchmarks[{i}]")
        _check_tasks(data, where)
        try:  # what to_json will write: strict JSON (no NaN/Infinity), string keys
            json.dumps(data, allow_nan=False, sort_keys=True)
        except (TypeError, ValueError) as e:
            raise ManifestError(f"{where}: not strict JSON ({e}; NaN and Infinity are not allowed). {_REPUBLISH}") from None
        kwargs = dict(data)
        kwargs["requirements"] = tuple(reqs)
        kwargs["benchmarks"] = tuple(data.get("benchmarks", []))
        kwargs["processors"] = tuple(data.get("processors", []))
        kwargs["tasks"] = tuple(data.get("tasks", []))
        return cls(**kwargs)

    # -- a suite --

    @property
    def task_names(self) -> list[str]:
        """A suite's tasks (the config's ``task`` values), in task-id order; ``[]`` for a one-task env."""
        return [str(t["task"]) for t in self.tasks]

    def task_record(self, task: str) -> dict[str, Any]:
        """A suite task's record (``tasks[i]``).

        Args:
            task: one of :attr:`task_names`.

        Returns:
            Its record.

        Raises:
            ConfigError: not a task of this suite (the message lists them).
        """
        record = _task_index(self.tasks).get(task)
        if record is not None:
            return record
        names = self.task_names
        listed = names[:10] + ([f"... {len(names) - 10} more"] if len(names) > 10 else [])
        raise ConfigError(
            f"{self.repo_id or self.name}: {task!r} is not one of its tasks; it has {listed or 'none (a one-task env)'}."
        )

    @classmethod
    def from_json(cls, text: str, *, where: str = MANIFEST_FILE) -> Manifest:
        """Read ``hub_env.json``'s text.

        Args:
            text: the text.
            where: names it in messages.

        Returns:
            The :class:`Manifest`.

        Raises:
            ManifestError: not JSON, or as :meth:`from_dict`.
        """
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise ManifestError(f"{where} is not valid JSON ({e}). Re-publish with push_env.") from None
        except (RecursionError, TypeError) as e:  # nested too deeply; not text at all
            raise ManifestError(f"{where} cannot be read as JSON ({type(e).__name__}). Re-publish with push_env.") from None
        return cls.from_dict(data, where=where)

    @classmethod
    def read(cls, folder: Path, *, where: str | None = None) -> Manifest:
        """Read a folder's ``hub_env.json``.

        Args:
            folder: the folder.
            where: names it in messages (default: the file's path).

        Returns:
            The :class:`Manifest`.

        Raises:
            ManifestError: there is none, or as :meth:`from_json`.
        """
        path = Path(folder, MANIFEST_FILE)
        where = where or str(path)
        if not path.is_file():
            raise ManifestError(
                f"{where} is missing: this is not an env repo published by push_env. Publish it with `push_env --env_dir=...`."
            )
        try:
            return cls.from_json(path.read_text(encoding="utf-8"), where=where)
        except UnicodeDecodeError:
            raise ManifestError(f"{where} is not UTF-8 text. Re-publish with push_env.") from None

    # -- checks that need no code --

    def verify_files(self, folder: Path, *, where: str, lazy: bool = False, skip: Collection[str] = ()) -> None:
        """Refuse a snapshot whose files differ from the manifest: tampered, missing, or unlisted code.

        Args:
            folder: the snapshot.
            where: names it in messages.
            lazy: leave the files fetched on demand (:func:`is_on_demand_file`: the dataset's data, the media) out; they are
                verified when fetched.
            skip: files verified at another time (still downloading, or verified already).

        Raises:
            IntegrityError: listing every file that is missing, differs, or is code the manifest does not list.
        """
        folder = Path(folder)
        problems = []
        for path, expected in sorted(self.files.items()):
            if (lazy and is_on_demand_file(path)) or path in skip:
                continue
            local = folder / path
            if not local.is_file():
                problems.append(f"  missing   {safe_text(path)}")
            elif sha256_file(local) != expected:
                problems.append(f"  tampered  {safe_text(path)} (sha256 differs from the manifest)")
        present = set(list_files(folder, skip=(MANIFEST_FILE,))) | set(executable_files(folder))
        for path in sorted(present - set(self.files)):
            if is_code_file(path) or path.endswith(EXECUTABLE_SUFFIXES):
                problems.append(f"  unlisted  {safe_text(path)} (code not covered by the manifest)")
        if problems:
            raise IntegrityError(
                f"{where}: {len(problems)} file(s) do not match the manifest:\n"
                + "\n".join(problems)
                + "\nDo not run this code. If you publish this repo, re-publish with push_env; otherwise ask its author."
            )
        if content_digest(self.files) != self.content_digest:
            raise IntegrityError(
                f"{where}: the manifest's content_digest does not match its file list. Re-publish with push_env."
            )


# --- a local env folder (what an author writes) -----------------------------------------------


#: The format version each manifest field appeared in (1 unless said).
_FIELD_SINCE = {f.name: f.metadata.get("since", 1) for f in fields(Manifest)}

_SPDX_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.+-]{0,63}$")


def card_license(project: dict[str, Any]) -> str | None:
    """The license a card may state for ``[project]``: the SPDX id it declares (``license = "MIT"`` or
    ``license = {text = "MIT"}``), lowercased as the Hub spells ids; ``"other"`` for a license file or a
    longer text; None when nothing is declared (the card then claims no license).

    >>> card_license({"license": "Apache-2.0"}), card_license({"license": {"file": "LICENSE"}}), card_license({})
    ('apache-2.0', 'other', None)
    """
    value = project.get("license")
    if isinstance(value, dict):
        value = value.get("text") if "text" in value else ("other" if value.get("file") else None)
    if value is None and project.get("license-files"):
        return "other"
    if not isinstance(value, str) or not value.strip():
        return None
    value = value.strip()
    return value.lower() if _SPDX_ID_RE.match(value) else "other"


@dataclass(frozen=True)
class EnvFolder:
    """A local env folder, read from its ``pyproject.toml`` without running any of its code."""

    root: Path
    name: str
    version: str
    description: str
    requirements: tuple[str, ...]
    env_entry_point: str
    config_entry_point: str
    files: tuple[str, ...]
    #: ``[tool.hub-envs] processors`` (tables; validated by load_env, see hub_envs.loading.processors)
    processors: tuple[dict[str, Any], ...] = ()
    #: ``[project] license`` as the card states it (:func:`card_license`); None when none is declared
    license: str | None = None
    #: ``[tool.hub-envs.media] gym_kwargs``: keyword arguments for the env that renders the card's GIF/MP4 (its
    #: camera, say), on top of the render size push_env asks for (:func:`hub_envs.harness.media.card_media_kwargs`)
    media_gym_kwargs: dict[str, Any] = field(default_factory=dict)
    #: ``[tool.hub-envs] tasks``: a benchmark suite's tasks, values of the config's ``task`` field, in task-id order
    #: (:func:`_suite_tasks`); empty: a one-task env
    tasks: tuple[str, ...] = ()

    @classmethod
    def read(cls, root: str | Path) -> EnvFolder:
        """Read an env folder: its ``pyproject.toml`` (``[project]`` and ``[tool.hub-envs]``) and its files.

        Args:
            root: the folder.

        Returns:
            The :class:`EnvFolder`.

        Raises:
            EnvFolderError: naming what is missing or malformed.
        """
        root = Path(root).resolve()
        if not root.is_dir():
            raise EnvFolderError(f"Env folder {root} does not exist. Pass the folder holding pyproject.toml and the env's code.")
        project_path = root / PROJECT_FILE
        if not project_path.is_file():
            raise EnvFolderError(
                f"{project_path} is missing. An env folder needs a pyproject.toml with\n"
                f'  [project] name = "my-env", dependencies = [...]\n'
                f'  [tool.hub-envs] env = "my_env:MyEnv", config = "my_env:MyEnvConfig"'
            )
        try:
            data = tomllib.loads(project_path.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise EnvFolderError(f"{project_path} is not valid TOML ({e}). Fix the syntax.") from None
        for table in ("project", "tool"):
            if not isinstance(data.get(table, {}), dict):
                raise EnvFolderError(
                    f"{project_path}: [{table}] must be a table, e.g. [{table}] on a line of its own. Fix the file."
                )
        project = data.get("project", {})
        tool = data.get("tool", {}).get("hub-envs")
        if not isinstance(tool, dict):
            raise EnvFolderError(
                f'{project_path}: no [tool.hub-envs] table. Add env = "module:EnvClass" and config = "module:ConfigClass".'
            )
        for key in ("env", "config"):
            if not isinstance(tool.get(key), str):
                raise EnvFolderError(
                    f'{project_path}: [tool.hub-envs] {key} is missing or not a string, e.g. {key} = "my_env:My{"Env" if key == "env" else "EnvConfig"}".'
                )
            if not ENTRY_POINT_RE.match(tool[key]):
                raise EnvFolderError(
                    f"{project_path}: [tool.hub-envs] {key} = {tool[key]!r} is not of the form 'module:Attribute', "
                    f'e.g. {key} = "my_env:My{"Env" if key == "env" else "EnvConfig"}" for a class in my_env.py.'
                )
        name = project.get("name")
        if not isinstance(name, str) or not name:
            raise EnvFolderError(f'{project_path}: [project] name is missing. Add name = "my-env".')
        deps = project.get("dependencies", [])
        if not isinstance(deps, list) or not all(isinstance(d, str) for d in deps):
            raise EnvFolderError(f"{project_path}: [project] dependencies must be a list of requirement strings.")
        # lazy: an isolated env's worker imports this module in a venv that may not hold packaging
        from packaging.requirements import InvalidRequirement, Requirement

        for dep in deps:
            try:
                Requirement(dep)
            except InvalidRequirement as e:
                raise EnvFolderError(f"{project_path}: dependency {dep!r} is not a valid requirement ({e}).") from None
        processors = tool.get("processors", [])
        if not isinstance(processors, list) or not all(isinstance(p, dict) for p in processors):
            raise EnvFolderError(
                f"{project_path}: [tool.hub-envs] processors must be a list of tables, e.g.\n"
                f'  [[tool.hub-envs.processors]]\n  name = "clip"\n  entry_point = "clip_action"\n  stage = "post"'
            )
        media_gym_kwargs = _media_gym_kwargs(tool.get("media", {}), project_path)
        tasks = _suite_tasks(tool.get("tasks"), project_path)
        files = list_files(root)
        clash = sorted({f.split("/")[0] for f in files} & {*GENERATED, REPRODUCTIONS_DIR})
        if clash:
            raise EnvFolderError(
                f"{root}: {clash} are generated by push_env (or, {REPRODUCTIONS_DIR}/, added by merged attestations) and "
                f"must not be in an env folder. Remove or rename them."
            )
        if not any(f.endswith(".py") for f in files):
            raise EnvFolderError(f"{root} has no .py file. Put the env and its config in a module next to pyproject.toml.")
        return cls(
            root=root,
            name=name,
            version=str(project.get("version", "0.0.0")),
            description=str(project.get("description", "")),
            requirements=tuple(deps),
            env_entry_point=tool["env"],
            config_entry_point=tool["config"],
            files=tuple(files),
            processors=tuple(processors),
            license=card_license(project),
            media_gym_kwargs=media_gym_kwargs,
            tasks=tasks,
        )


_TASKS_EXAMPLE = '  [tool.hub-envs]\n  tasks = ["reach-left", "reach-right", "reach-far"]   # values of the config\'s task field'
#: A task name: what LeRobot's ``--env.task=a,b`` can list (no comma), one line of printable text.
_TASK_RE = re.compile(r"^[^,\x00-\x1f\x7f]{1,200}$")


def _suite_tasks(value: Any, project_path: Path) -> tuple[str, ...]:
    """``[tool.hub-envs] tasks`` checked without running code: absent (a one-task env), or at least two distinct task
    names (the values of the config's ``task`` field; whether the config and the env accept each is checked at push)."""
    if value is None:
        return ()
    if not isinstance(value, list) or not all(isinstance(t, str) for t in value):
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs] tasks must be a list of task names (strings), e.g.\n{_TASKS_EXAMPLE}"
        )
    if len(value) < 2:
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs] tasks lists {len(value)} task; a suite has at least two. For one task, "
            f"remove the key and set the config's task field's default."
        )
    bad = [t for t in value if not _TASK_RE.match(t) or t != t.strip()]
    if bad:
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs] tasks has {[safe_text(b) for b in bad]}: a task name is one line of 1 to 200 "
            f"characters, without commas (LeRobot's --env.task=a,b lists tasks with them) or surrounding spaces."
        )
    twice = sorted(t for t, n in collections.Counter(value).items() if n > 1)
    if twice:
        raise EnvFolderError(f"{project_path}: [tool.hub-envs] tasks names {twice} more than once; list each task once.")
    return tuple(value)


#: What ``[tool.hub-envs.media]`` may hold.
MEDIA_KEYS = ("gym_kwargs",)
_MEDIA_EXAMPLE = '  [tool.hub-envs.media]\n  gym_kwargs = { render_camera = { target = "drone", distance = 0.5 } }'


def _media_gym_kwargs(media: Any, project_path: Path) -> dict[str, Any]:
    """``[tool.hub-envs.media] gym_kwargs`` checked: a table of plain values (no dates), string keys."""
    if not isinstance(media, dict):
        raise EnvFolderError(f"{project_path}: [tool.hub-envs] media must be a table, e.g.\n{_MEDIA_EXAMPLE}")
    unknown = sorted(set(media) - set(MEDIA_KEYS))
    if unknown:
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs.media] has unknown keys {unknown}; it takes {list(MEDIA_KEYS)}, e.g.\n{_MEDIA_EXAMPLE}"
        )
    kwargs = media.get("gym_kwargs", {})
    if not isinstance(kwargs, dict):
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs.media] gym_kwargs must be a table of the env's keyword arguments, e.g.\n{_MEDIA_EXAMPLE}"
        )
    try:  # the card states these values: plain JSON values only (TOML dates and times are not keyword values)
        json.dumps(kwargs, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise EnvFolderError(
            f"{project_path}: [tool.hub-envs.media] gym_kwargs holds a value that is not a string, number, boolean, "
            f"array or table ({e}). Write the value as one of those."
        ) from None
    return kwargs
