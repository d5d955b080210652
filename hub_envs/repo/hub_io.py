"""Hub I/O: resolve a revision to a commit sha, fetch a snapshot, publish a folder as one commit.

The only module that talks to the Hub. It uses the unmodified ``huggingface_hub`` client and its
cache, reads ``HF_ENDPOINT`` / ``HF_TOKEN`` / ``HF_HUB_OFFLINE`` as the client does, and turns the
client's errors into hub-envs' own (:mod:`hub_envs.errors`) with a next step in the message.

"""

from __future__ import annotations

import concurrent.futures
import contextlib
import hashlib
import json
import logging
import os
import re
import secrets
import threading
import warnings
from collections.abc import Callable, Iterable
from pathlib import Path
from urllib.parse import unquote, urljoin, urlsplit

from huggingface_hub import (
    CommitOperationAdd,
    CommitOperationDelete,
    HfApi,
    constants,
    get_token,
    hf_hub_download,
    hf_hub_url,
    snapshot_download,
    try_to_load_from_cache,
)
from huggingface_hub.errors import (
    EntryNotFoundError,
    HfHubHTTPError,
    LocalEntryNotFoundError,
    OfflineModeIsEnabled,
    RepositoryNotFoundError,
)
from huggingface_hub.errors import RevisionNotFoundError as HfRevisionNotFoundError
from huggingface_hub.utils import build_hf_headers
from huggingface_hub.utils import tqdm as hf_tqdm

from hub_envs._compat import NETWORK_ERRORS, TRANSFER_ERRORS, install_response_hook, lfs_instead_of_xet, stream_file
from hub_envs._text import safe_text
from hub_envs.errors import (
    ConcurrentPushError,
    EnvRepoNotFoundError,
    HostileResponseError,
    HubAccessError,
    HubError,
    IntegrityError,
    OfflineNotCachedError,
    RevisionNotFoundError,
)
from hub_envs.repo import hub_cache
from hub_envs.repo.format import (
    DATASET_DIR,
    MANIFEST_FILE,
    beyond_manifest,
    is_commit_sha,
    is_on_demand_file,
)
from hub_envs.repo.hub_cache import (  # noqa: F401  (the cache's side, re-exported: hub_io.offline(), hub_io.REPO_TYPE, ...)
    DATASET_REPO_TYPE,
    REPO_TYPE,
    cache_snapshots_dir,
    cached_snapshot,
    check_snapshot_layout,
    drop_snapshot,
    endpoint,
    normalized_revision,
    offline,
    snapshot_cache_dir,
    snapshot_origin,
)

logger = logging.getLogger(__name__)


class Snapshot(hub_cache.Snapshot):
    """A repo at one commit, on local disk (:class:`hub_envs.repo.hub_cache.Snapshot`), whose background downloads' errors
    :meth:`wait` raises as hub-envs errors."""

    def wait(self) -> None:
        """Wait for the files still downloading in the background; a failed download raises the hub-envs
        error :func:`translate_hub_errors` makes of it. The caller verifies the files."""
        with translate_hub_errors(self.repo_id, self.sha):
            super().wait()


# --- what a hostile endpoint could make the client write ----------------------------------------

_HUB_ETAG = re.compile(r"[0-9a-f]{40}|[0-9a-f]{64}")  # git blob sha1, or the sha256 of an LFS/Xet file
_SHA256 = re.compile(r"[0-9a-f]{64}")  # an LFS file's oid, a Xet file's hash
#: the API answers whose bodies huggingface_hub builds cache paths from: a repo's info (``sha``, ``siblings``) with
#: or without a revision, its tree and paths-info listings (``path``, ``lfs.oid``, ``xetHash``)
_REPO_API = r"/api/(?:models|datasets|spaces)/[^/]+/[^/]+"
_CHECKED_APIS = {
    "revision": re.compile(_REPO_API + r"(?:/revision/.*)?/?"),
    "tree": re.compile(_REPO_API + r"/tree/.*"),
    "paths-info": re.compile(_REPO_API + r"/paths-info/.*"),
}
_NEXT_PAGE = re.compile(r'<([^>]*)>\s*;[^,]*\brel="?next"?', re.IGNORECASE)  # a paginated list's next page (``Link``)


def _refuse(url: str, what: str, why: str = "huggingface_hub would have used it as a file name in the cache") -> None:
    raise HostileResponseError(
        f"The endpoint {safe_text(urlsplit(url).netloc)} answered {safe_text(url)} with {what}: no Hub sends that, and "
        f"{why}. Refused before anything was written. "
        f"Check HF_ENDPOINT (and use https to a Hub you trust: plain http on a shared network can be rewritten)."
    )


def _escapes_repo(name: object) -> bool:
    """Whether a file name an answer lists could not be a path inside the repo (empty, absolute, ``..``, ``\\``, NUL)."""
    if not isinstance(name, str) or not name or "\\" in name or "\0" in name:
        return True
    return any(p in ("", ".", "..") for p in name.split("/"))


def _api_kind(url: str) -> str | None:
    """Which checked API answer (:data:`_CHECKED_APIS`) ``url`` asks for, if any."""
    path = unquote(urlsplit(url).path)
    return next((kind for kind, pattern in _CHECKED_APIS.items() if pattern.fullmatch(path)), None)


def _normalized_etag(value: str) -> str:
    return value.lstrip("W/").strip('"')  # huggingface_hub's own _normalize_etag, character for character (0.35 and 1.x)


def check_hub_response(method: str, url: str, status: int, headers, read_body) -> None:
    """Refuse an answer whose commit id, ETag, redirect or file names are not of the forms the Hub uses.

    huggingface_hub (0.35 and 1.x alike) builds cache paths from them without checking: the blob path
    from the ETag (``blobs/<etag>``), the snapshot folder from ``X-Repo-Commit`` or the revision API's
    ``sha``, files from its ``siblings`` or the tree's ``path``, and (1.x, Xet) a blob from the tree's
    ``lfs.oid``. A lying endpoint could write anywhere the user can (a ``.pth`` into site-packages,
    hub-envs' trust list) before any hub-envs check ran. Installed on huggingface_hub's HTTP client when
    this module is imported (see :func:`hub_envs._compat.install_response_hook`), so it runs on every
    answer the client receives, each hop of a redirect included, whatever its URL:

    * ``X-Repo-Commit``: 40 lowercase hex digits; ``X-Linked-Etag``: a 40- or 64-hex digest; ``X-Xet-Hash``:
      64 hex digits.
    * ``ETag``: a 40- or 64-hex digest on every answer huggingface_hub could take a file's metadata from (any
      but an error): one to a ``/resolve/`` URL, any answer to a ``HEAD`` (the metadata request, which follows
      redirects to other paths of the same host: the final answer, wherever it is, is the one used), and any
      answer that names a commit or a linked file (the client refuses metadata without ``X-Repo-Commit``).
    * The repo-info, tree and paths-info API answers: ``sha`` a commit id, every listed ``path`` /
      ``rfilename`` inside the repo, an ``lfs.oid`` or ``xetHash`` 64 hex digits. Their bodies are checked
      by URL, so a redirect of one (``Location``) or its next page (``Link``) must be an answer of the
      same API: otherwise the body the client parses would come from a URL the check does not read.

    Args:
        method: the request's method (``"HEAD"``, ``"GET"``...).
        url: the URL this answer came from (one hop of a redirect chain).
        status: the answer's status code.
        headers: the answer's headers (case-insensitive mapping).
        read_body: returns the answer's body; called only for the small API answers above.

    Raises:
        HostileResponseError: before the client uses the answer, naming the endpoint, the URL and the value.
    """
    commit = headers.get("X-Repo-Commit")
    if commit is not None and not is_commit_sha(commit):
        _refuse(url, f"X-Repo-Commit {commit[:80]!r} (a commit id is 40 lowercase hex digits)")
    xet_hash = headers.get("X-Xet-Hash")
    if xet_hash is not None and not _SHA256.fullmatch(xet_hash):
        _refuse(url, f"X-Xet-Hash {xet_hash[:80]!r} (a Xet file's hash is 64 hex digits)")
    file_metadata = status < 400 and (  # an error answer's ETag names nothing: the client raises
        "/resolve/" in unquote(urlsplit(url).path)
        or method.upper() == "HEAD"
        or any(h in headers for h in ("X-Repo-Commit", "X-Linked-Etag", "X-Linked-Size"))
    )
    for name in ("X-Linked-Etag", "ETag") if file_metadata else ("X-Linked-Etag",):
        value = headers.get(name)
        if value is not None and not _HUB_ETAG.fullmatch(_normalized_etag(value)):
            _refuse(url, f"{name} {value[:80]!r} (a file's ETag is its 40-hex git or 64-hex sha256 digest)")
    kind = _api_kind(url)
    if kind is None:
        return
    _check_api_links(url, kind, status, headers)
    if 200 <= status < 300:
        _check_api_body(url, read_body)


def _check_api_links(url: str, kind: str, status: int, headers) -> None:
    """A redirect or next page of a checked API answer is an answer of the same API (whose body is then checked)."""
    location = headers.get("Location") if 300 <= status < 400 else None
    if location is not None and _api_kind(urljoin(url, location)) != kind:
        _refuse(
            url,
            f"a redirect to {location[:200]!r}",
            f"the {kind} answer the client would parse from there is not where hub-envs checks it",
        )
    for nxt in _NEXT_PAGE.findall(headers.get("Link") or ""):
        if _api_kind(urljoin(url, nxt)) != kind:
            _refuse(
                url,
                f"a next page at {nxt[:200]!r}",
                f"the {kind} listing the client would read from there is not where hub-envs checks it",
            )


def _check_api_body(url: str, read_body) -> None:
    """The names and ids a repo-info, tree or paths-info answer lists are of the Hub's forms."""
    try:
        info = json.loads(read_body())
    except (ValueError, UnicodeDecodeError):
        return  # not JSON: the client raises its own error
    if isinstance(info, dict):
        sha = info.get("sha")
        if sha is not None and not is_commit_sha(sha):
            _refuse(url, f"a repo sha {str(sha)[:80]!r} (a commit id is 40 lowercase hex digits)")
        entries, key = info.get("siblings") or [], "rfilename"
    elif isinstance(info, list):
        entries, key = info, "path"
    else:
        return
    for entry in entries if isinstance(entries, list) else [entries]:
        entry = entry if isinstance(entry, dict) else {}
        name = entry.get(key)
        if _escapes_repo(name):
            _refuse(url, f"a file name {str(name)[:80]!r} that escapes the repo or cannot be a file's")
        lfs = entry.get("lfs")
        oid = lfs.get("oid", lfs.get("sha256")) if isinstance(lfs, dict) else None
        for what, value in (("an LFS oid", oid), ("a xetHash", entry.get("xetHash"))):
            if value is not None and not (isinstance(value, str) and _SHA256.fullmatch(value)):
                _refuse(url, f"{what} {str(value)[:80]!r} for {safe_text(name)} (64 hex digits on the Hub)")


def ensure_checked() -> None:
    """Put :func:`check_hub_response` back on huggingface_hub's client if something replaced the client factory
    since this module was imported (``configure_http_backend`` / ``set_client_factory``). Cheap when it is there;
    every call hub-envs makes to the Hub passes through here (:func:`api`, :func:`translate_hub_errors`)."""
    install_response_hook(check_hub_response)


ensure_checked()


def api(token: str | None = None) -> HfApi:
    """A fresh client at the current endpoint (never the one captured when huggingface_hub was imported), with the
    endpoint check installed.

    Args:
        token: the Hub token (None: huggingface_hub's own).

    Returns:
        An ``HfApi``.
    """
    ensure_checked()
    return HfApi(endpoint=constants.ENDPOINT, token=token)


#: The largest whoami answer read (the Hub's lists an account's organizations: a few KiB).
_WHOAMI_MAX_BYTES = 1 << 20


def _whoami(token: str | None, repo_id: str) -> tuple[int, dict | None]:
    """``(status, answer)`` of ``GET /api/whoami-v2`` with ``token``, or anonymously when it is None (huggingface_hub's
    ``whoami`` refuses to ask without a token, but an open loopback server answers anonymous callers)."""
    url = f"{constants.ENDPOINT}/api/whoami-v2"
    with translate_hub_errors(repo_id, None):
        with stream_file(url, build_hf_headers(token=token or False), constants.HF_HUB_ETAG_TIMEOUT) as (status, _, _, chunks):
            body = bytearray()
            for chunk in chunks:
                body += chunk
                if len(body) > _WHOAMI_MAX_BYTES:
                    break
    if status != 200:
        return status, None
    try:
        answer = json.loads(bytes(body))
    except ValueError:
        answer = None
    return status, answer if isinstance(answer, dict) else None


def check_write_access(repo_id: str, *, token: str | None = None, pull_request: bool = False) -> str:
    """Refuse, before anything is built, a push the Hub would refuse at the end: it asks the Hub who the caller is.

    Args:
        repo_id: ``namespace/name``, the repo about to be written.
        token: the token the push will send; default: huggingface_hub's (``HF_TOKEN``, else ``hf auth login``'s).
        pull_request: the write is a pull request (an attestation), which any account may open on a repo it can
            read: the namespace is not checked.

    Returns:
        The account the Hub says the caller is (an open loopback server answers anonymous callers too).

    Raises:
        HubAccessError: no token and the Hub wants one; the Hub refuses the token; the token is read-only; the
            account is neither the namespace nor one of its organizations with write access (unless the Hub says
            the account manages every repo, as the loopback server's own account does, or ``pull_request``). A
            fine-grained token's scopes are left to the Hub to judge at publish time.
        HubError: the Hub cannot be reached, or HF_HUB_OFFLINE is set.
    """
    where = f"{repo_id} at {constants.ENDPOINT}"
    namespace = repo_id.split("/")[0]
    if offline():
        raise HubError(f"{where}: HF_HUB_OFFLINE is set, so nothing can be published. Unset it and run again.")
    effective = token or get_token()
    doing = "open a pull request" if pull_request else "publish"
    need = "a token with write access" + ("" if pull_request else f" to {namespace!r}")
    tail = "nothing was run" if pull_request else "nothing was built or published"
    status, info = _whoami(effective, repo_id)
    if status in (401, 403) and not effective:
        raise HubAccessError(
            f"{where}: no token is set, and this Hub needs one to {doing}. Set HF_TOKEN to {need} (or run "
            f"`hf auth login`), then run again; {tail}."
        )
    if status in (401, 403):
        raise HubAccessError(
            f"{where}: the Hub refused the token ({status}: invalid, expired or revoked). Set HF_TOKEN to {need} "
            f"(or run `hf auth login`); {tail}."
        )
    if status != 200 or info is None or not isinstance(info.get("name"), str):
        raise HubError(f"{where}: the Hub answered {status} to whoami, not an account. Check HF_ENDPOINT; {tail}.")
    name = info["name"]
    auth = info.get("auth") if isinstance(info.get("auth"), dict) else {}
    role = (auth.get("accessToken") or {}).get("role") if isinstance(auth.get("accessToken"), dict) else None
    if role == "read":
        raise HubAccessError(
            f"{where}: the token of {safe_text(name)!r} is read-only, and this Hub needs {need} to {doing}. Create one "
            f"and set HF_TOKEN to it (or run `hf auth login`); {tail}."
        )
    orgs = [o for o in info.get("orgs") or [] if isinstance(o, dict) and isinstance(o.get("name"), str)]
    writable = {name.lower()} | {o["name"].lower() for o in orgs if o.get("roleInOrg") != "read"}
    if pull_request or role == "fineGrained" or info.get("managesEveryRepo") is True or namespace.lower() in writable:
        return name
    theirs = ", ".join(sorted(repr(safe_text(o["name"])) for o in orgs)) or "none"
    raise HubAccessError(
        f"{where}: the account {safe_text(name)!r} (HF_TOKEN / `hf auth login`) cannot write to the namespace "
        f"{namespace!r}: it is neither that account nor one of its organizations with write access (its "
        f"organizations: {theirs}). Push to {safe_text(name)}/{repo_id.split('/')[1]}, or use a token of an account "
        f"that may write to {namespace!r}; nothing was built or published."
    )


def _cache_snapshot_dir(repo_id: str, sha: str, cache_dir: str | Path | None) -> Path:
    return snapshot_cache_dir(repo_id, sha, cache_dir)


def _sent_a_token(response) -> bool:
    """Whether the request of ``response`` (requests' or httpx's, both keep it) carried an Authorization header."""
    try:
        return bool(response.request.headers.get("authorization"))
    except Exception:  # noqa: BLE001 - no request kept: say what the Hub said, a refused token
        return True


@contextlib.contextmanager
def translate_hub_errors(repo_id: str, revision: str | None):
    """Inside the block, huggingface_hub's and the HTTP library's errors become hub-envs errors that say what to do next.

    Args:
        repo_id: the repo the block works on (messages name it).
        revision: its revision, or None.

    Raises:
        EnvRepoNotFoundError, RevisionNotFoundError: no such repo or revision.
        HubAccessError: a token is needed, or refused.
        OfflineNotCachedError: offline (or the Hub unreachable), and not in the cache.
        HubError: any other failure of the Hub or the transfer (the message says whether to retry).
    """
    where = f"{repo_id}@{revision}" if revision else repo_id
    ensure_checked()
    try:
        yield
    except RuntimeError as e:
        # huggingface_hub wraps a failed LFS upload: RuntimeError("Error while uploading '<path>' to the Hub.")
        cause = e.__cause__
        if isinstance(cause, RuntimeError) and "client has been closed" in str(cause):
            # huggingface_hub 1.x closes its HTTP client after a network error; the other upload threads then fail so
            raise HubError(
                f"{where}: the connection to the Hub at {constants.ENDPOINT} broke during an upload ({safe_text(str(e))}). "
                f"Retry: nothing was committed, and files the Hub already holds are not sent again."
            ) from e
        if not isinstance(cause, (HfHubHTTPError, *NETWORK_ERRORS, *TRANSFER_ERRORS)) or e is cause:
            raise
        with translate_hub_errors(repo_id, revision):
            raise cause from None
    except HfRevisionNotFoundError as e:
        raise RevisionNotFoundError(
            f"{repo_id} has no revision {revision!r} at {constants.ENDPOINT}. List its branches and tags with "
            f"`HfApi().list_repo_refs({repo_id!r})` or pin a commit sha from its history."
        ) from e
    except RepositoryNotFoundError as e:
        raise EnvRepoNotFoundError(
            f"Env repo {repo_id!r} was not found at {constants.ENDPOINT}. Check the id; if it is private, set HF_TOKEN; "
            f"if it lives on another Hub, set HF_ENDPOINT."
        ) from e
    except (LocalEntryNotFoundError, OfflineModeIsEnabled) as e:
        raise OfflineNotCachedError(
            f"{where} is not in the local cache and the Hub cannot be used (offline mode or unreachable {constants.ENDPOINT}). "
            f"Load it once online (unset HF_HUB_OFFLINE), or pin a sha that is already cached."
        ) from e
    except EntryNotFoundError as e:
        raise HubError(f"{where}: a file is missing on the Hub ({e}). Re-publish the env with push_env.") from e
    except HfHubHTTPError as e:
        status = getattr(e.response, "status_code", "?")
        if status == 401:
            said = "refused the token" if _sent_a_token(e.response) else "wants a token, and none was sent"
            raise HubError(
                f"{where}: the Hub at {constants.ENDPOINT} {said} (401). Set HF_TOKEN to a token with access "
                f"(or run `hf auth login`)."
            ) from e
        raise HubError(f"{where}: the Hub at {constants.ENDPOINT} answered {status}: {e}. Retry, or check the server.") from e
    except NETWORK_ERRORS as e:
        raise HubError(
            f"{where}: cannot reach the Hub at {constants.ENDPOINT} ({type(e).__name__}). Check HF_ENDPOINT and the network, "
            f"or set HF_HUB_OFFLINE=1 to use the cache."
        ) from e
    except TRANSFER_ERRORS as e:  # e.g. the connection broke mid-file (not retried by the client)
        raise HubError(
            f"{where}: the transfer from {constants.ENDPOINT} broke off ({type(e).__name__}: {e}). Retry: the files that "
            f"arrived are kept, the rest is fetched again."
        ) from e
    except OSError as e:
        if "Consistency check failed" not in str(e):  # huggingface_hub: size of a downloaded file is wrong
            raise
        raise HubError(f"{where}: a downloaded file was incomplete ({e}). Retry; the file is fetched again.") from e


def resolve_snapshot(
    repo_id: str,
    revision: str | None = None,
    *,
    token: str | None = None,
    cache_dir: str | Path | None = None,
    force_download: bool = False,
    lazy: bool = False,
    first: Callable[[str], bool] | None = None,
) -> Snapshot:
    """Resolve ``revision`` to a commit sha and make sure its files are on disk.

    A cached 40-hex sha is served without any request, so a pinned warm load works offline and is fast. A branch or tag
    asks the Hub which commit it names (or the cache's refs when offline).

    Args:
        repo_id: the env repo.
        revision: a branch, tag or sha (None: main).
        token: the Hub token (None: huggingface_hub's own).
        cache_dir: the cache (None: ``HF_HUB_CACHE``).
        force_download: download again even what the cache holds.
        lazy: leave out the files fetched on demand (the dataset's data and the card's media:
            :func:`hub_envs.repo.format.is_on_demand_file`; fetch them with :func:`fetch_dataset_files`,
            :func:`fetch_files`) and what the manifest does not cover (:func:`hub_envs.repo.format.beyond_manifest`).
        first: return once the files it accepts are on disk; the others keep downloading in the background
            (:attr:`Snapshot.pending`; :meth:`Snapshot.wait` for them).

    Returns:
        The :class:`Snapshot` (not verified: the caller checks it against its manifest).

    Raises:
        EnvRepoNotFoundError, RevisionNotFoundError, OfflineNotCachedError, HubError: as :func:`translate_hub_errors`.
        HostileResponseError: the endpoint answered what huggingface_hub would have written outside the cache.
    """
    revision = normalized_revision(revision)
    if not force_download and (cached := cached_snapshot(repo_id, revision, cache_dir)) is not None:
        return cached
    with translate_hub_errors(repo_id, revision):
        if offline():
            path = snapshot_download(repo_id, revision=revision, repo_type=REPO_TYPE, cache_dir=cache_dir, local_files_only=True)
            return Snapshot(repo_id, revision, Path(path).name, Path(path), from_cache=True)
        # one request for the commit and its file list (snapshot_download would ask again, and 1.x lists the tree too)
        info = api(token).repo_info(repo_id, revision=revision, repo_type=REPO_TYPE)
        sha = info.sha
        _check_resolved(repo_id, revision, sha)
        names = [s.rfilename for s in info.siblings or []]
        if lazy:  # nor .gitattributes and reproductions/ (beyond the manifest), which nothing of an env reads
            names = [n for n in names if not is_on_demand_file(n) and (n == MANIFEST_FILE or not beyond_manifest(n))]
        path, pending, pool = _fetch(
            repo_id, sha, names, token=token, cache_dir=cache_dir, force_download=force_download, first=first
        )
    snap = Snapshot(repo_id, revision, sha, path, from_cache=False, pending=pending, fetched=frozenset(names), _pool=pool)
    try:
        _check_resolved(repo_id, revision, path.name)
    except BaseException:
        snap.cancel()
        raise
    return snap


#: Files downloaded at once (as snapshot_download's default).
MAX_WORKERS = 8


def _fetch(
    repo_id: str,
    sha: str,
    names: Iterable[str],
    *,
    token: str | None,
    cache_dir: str | Path | None,
    force_download: bool = False,
    first: Callable[[str], bool] | None = None,
) -> tuple[Path, dict[str, concurrent.futures.Future], concurrent.futures.ThreadPoolExecutor]:
    """Download ``names`` of ``repo_id`` at commit ``sha`` into the cache, ``MAX_WORKERS`` at a time, each with
    ``hf_hub_download`` (what snapshot_download does per file; huggingface_hub's cache is safe for concurrent
    downloads; small files take one request instead of two: :func:`_get_into_cache`). Returns the snapshot folder
    once the files ``first`` accepts (all when None) are there, and the futures of the others, which start then (so they do not slow the first down) and download while the caller
    goes on, and the pool (``shutdown(wait=True)`` joins its threads). Call inside :func:`translate_hub_errors`."""
    names = sorted(set(names))
    bar = hf_tqdm(total=len(names), desc=f"Fetching {len(names)} files", unit="file")
    left, lock = [len(names)], threading.Lock()

    def one(name: str) -> str:
        try:
            got = _get_into_cache(repo_id, sha, name, token=token, cache_dir=cache_dir, force_download=force_download)
            return got or hf_hub_download(
                repo_id, name, revision=sha, repo_type=REPO_TYPE, cache_dir=cache_dir, token=token, force_download=force_download
            )
        finally:
            with lock:
                bar.update()
                left[0] -= 1
                if not left[0]:
                    bar.close()

    if not names:
        bar.close()
    pool = concurrent.futures.ThreadPoolExecutor(max_workers=MAX_WORKERS, thread_name_prefix="hub-envs-fetch")
    later = [n for n in names if first is not None and n != MANIFEST_FILE and not first(n)]
    futures = {name: pool.submit(one, name) for name in names if name not in later}
    path = _cache_snapshot_dir(repo_id, sha, cache_dir)
    try:
        for name, future in futures.items():  # where they landed: snapshots/<sha>/<name>
            path = Path(future.result()).parents[len(Path(name).parts) - 1]
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
        raise
    # the others start once the first are in: they download while the caller works, not against the first
    pending = {name: pool.submit(one, name) for name in later}
    if not pending:
        pool.shutdown(wait=True)
    return path, pending, pool


#: The largest file :func:`_get_into_cache` fetches itself; bigger ones go through hf_hub_download (progress bar, resume).
DIRECT_GET_MAX_BYTES = 16 * 2**20


def _get_into_cache(
    repo_id: str, sha: str, name: str, *, token: str | None, cache_dir: str | Path | None, force_download: bool = False
) -> str | None:
    """Fetch ``name`` at commit ``sha`` with one ``GET`` into huggingface_hub's cache, laid out as the client lays it
    out (``blobs/<etag>``; ``snapshots/<sha>/<name>``, a relative symlink to it), so the client, LeRobot's loader and
    ``scan_cache_dir`` take it for their own; returns its path there.

    ``hf_hub_download`` asks for a file's metadata first (a ``HEAD``), then for its content: two round trips per file,
    which for the small files a cold load needs before anything can run is most of its download time (measured:
    ``benchmarks/bench_load.py``, ``first_files_direct_vs_hf``). Here the commit and the ETag come with the content
    (the headers of the Hub's own answer, before any redirect to a CDN). Anything but a plain answer returns None,
    having written nothing, and the caller asks ``hf_hub_download``, with its retries, resumes and errors: a status
    other than 200, another commit, an ETag missing or not of the Hub's forms, no ``Content-Length`` or more than
    :data:`DIRECT_GET_MAX_BYTES`, a body of another length or whose digest is not its ETag (git's blob sha1, or the
    sha256 of an LFS file), a compressed body, a broken transfer, a partial download of huggingface_hub's own to
    resume, a file system without symlinks (or ``HF_HUB_DISABLE_SYMLINKS``), a name with characters that are not
    printable. A blob already cached under the ETag is used only if its content is what the ETag says (its body is
    read all the same, so that the connection is reused). An answer :func:`check_hub_response` refuses is refused
    (:class:`~hub_envs.errors.HostileResponseError`).

    The blob is written under a random temporary name (``<etag>.<random>.incomplete``, huggingface_hub 1.x's own
    pattern) and renamed, the symlink made under a temporary name in ``blobs/`` and renamed over the pointer: a
    process reading the cache meanwhile sees the old file or the new one, never none (huggingface_hub removes a
    pointer before re-linking it) and never a file the commit does not list.
    """
    if (
        _escapes_repo(name)
        or not name.isprintable()
        or getattr(constants, "HF_HUB_DISABLE_SYMLINKS", False)  # 1.x: files, not links, in snapshots/
    ):
        return None
    snapshot = _cache_snapshot_dir(repo_id, sha, cache_dir)
    pointer = snapshot.joinpath(*name.split("/"))
    if not force_download and pointer.is_file():
        return str(pointer)
    blobs = snapshot.parent.parent / "blobs"
    url = hf_hub_url(repo_id, name, revision=sha, repo_type=REPO_TYPE, endpoint=constants.ENDPOINT)
    headers = build_hf_headers(token=token)
    headers["Accept-Encoding"] = "identity"  # the bytes as stored: their length and digest are the file's
    link = partial = None
    try:
        with stream_file(url, headers, constants.HF_HUB_DOWNLOAD_TIMEOUT) as (status, hub, final, chunks):
            etag = (hub.get("X-Linked-Etag") or hub.get("ETag") or "").removeprefix("W/").strip('"')
            length = final.get("Content-Length") or ""
            if (
                status != 200
                or hub.get("X-Repo-Commit") != sha
                or not _HUB_ETAG.fullmatch(etag)
                or not length.isdigit()
                or int(length) > DIRECT_GET_MAX_BYTES
                or hub.get("X-Linked-Size", length) != length
                or final.get("Content-Encoding", "identity").strip().lower() != "identity"
                or (blobs / f"{etag}.incomplete").exists()  # 0.x's partial download of it: hf_hub_download resumes it
            ):
                return None
            size, blob = int(length), blobs / etag
            blobs.mkdir(parents=True, exist_ok=True)
            # the link first, under a name of its own in blobs/ (in the snapshot folder a reader would take it for a
            # file of the commit): where symlinks cannot be made, nothing else is written
            link = blobs / f"{etag}.{secrets.token_hex(4)}.link.incomplete"
            os.symlink(os.path.relpath(blob, pointer.parent), link)
            if force_download or _digest_of(blob, etag) != etag:  # missing, or not what its name says: written anew
                digest = _etag_digest(etag, size)
                scratch = blobs / f"{etag}.{secrets.token_hex(4)}.incomplete"
                fd = os.open(scratch, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as to any file
                partial = scratch
                got = 0
                with open(fd, "wb") as f:
                    for chunk in chunks:
                        got += len(chunk)
                        if got > size:
                            return None
                        digest.update(chunk)
                        f.write(chunk)
                if got != size or digest.hexdigest() != etag:
                    return None
                os.replace(partial, blob)
                partial = None
            else:  # the blob is here already: the body is read to its end all the same, so the connection is reused
                got = 0
                for chunk in chunks:
                    got += len(chunk)
                    if got > size:
                        return None
            pointer.parent.mkdir(parents=True, exist_ok=True)
            os.replace(link, pointer)
            link = None
    except HostileResponseError:
        raise
    except Exception as e:  # noqa: BLE001 - hf_hub_download asks again and raises what it raises
        logger.debug("%s@%s: fetching %s with one GET failed (%r); huggingface_hub fetches it", repo_id, sha, name, e)
        return None
    finally:
        for leftover in (link, partial):
            if leftover is not None:
                with contextlib.suppress(OSError):
                    leftover.unlink()
    return str(pointer)


def _etag_digest(etag: str, size: int):
    """The hash whose hex digest is a file's ETag: sha256 (an LFS or Xet file), else git's blob sha1."""
    return hashlib.sha256() if len(etag) == 64 else hashlib.sha1(b"blob %d\0" % size)


def _digest_of(blob: Path, etag: str) -> str | None:
    """The ETag-kind digest of a cached blob (None if it is missing or larger than :data:`DIRECT_GET_MAX_BYTES`): a
    blob another load wrote from a body the manifest later refused is not trusted for its name."""
    try:
        size = blob.stat().st_size
        if size > DIRECT_GET_MAX_BYTES:
            return None
        digest = _etag_digest(etag, size)
        with open(blob, "rb") as f:
            while block := f.read(1 << 20):
                digest.update(block)
        return digest.hexdigest()
    except OSError:
        return None


def fetch_files(
    repo_id: str, sha: str, names: Iterable[str], *, token: str | None = None, cache_dir: str | Path | None = None
) -> Path:
    """Download files of a commit into the cache (those already there are not fetched again).

    Args:
        repo_id: the env repo.
        sha: the commit.
        names: repo paths.
        token: the Hub token (None: huggingface_hub's own).
        cache_dir: the cache (None: ``HF_HUB_CACHE``).

    Returns:
        The snapshot folder. The caller verifies the files against the manifest.

    Raises:
        HubError: as :func:`translate_hub_errors`.
    """
    with translate_hub_errors(repo_id, sha):
        path, _, _ = _fetch(repo_id, sha, names, token=token, cache_dir=cache_dir)
    _check_resolved(repo_id, sha, path.name)
    return path


def _download(
    repo_id: str, sha: str, *, token: str | None, cache_dir: str | Path | None, force_download: bool, **patterns
) -> str:
    """``snapshot_download`` of one commit of an env repo (``patterns``: its allow/ignore patterns)."""
    return snapshot_download(
        repo_id, revision=sha, repo_type=REPO_TYPE, cache_dir=cache_dir, token=token, force_download=force_download, **patterns
    )


def fetch_dataset_files(
    repo_id: str, sha: str, *, token: str | None = None, cache_dir: str | Path | None = None, force_download: bool = False
) -> Path:
    """Download the dataset folder of a commit into the cache (files already there are not fetched again).

    Args:
        repo_id: the env repo.
        sha: the commit.
        token: the Hub token (None: huggingface_hub's own).
        cache_dir: the cache (None: ``HF_HUB_CACHE``).
        force_download: download again even what the cache holds.

    Returns:
        The snapshot folder. The caller verifies the files against the manifest.

    Raises:
        HubError: as :func:`translate_hub_errors`.
    """
    with translate_hub_errors(repo_id, sha):
        path = _download(
            repo_id, sha, token=token, cache_dir=cache_dir, force_download=force_download, allow_patterns=[f"{DATASET_DIR}/*"]
        )
    _check_resolved(repo_id, sha, Path(path).name)
    return Path(path)


def _check_resolved(repo_id: str, requested: str | None, sha: str | None) -> None:
    """The Hub answered ``sha`` for ``requested``: a commit id, and the very one asked for when a sha was asked."""
    if not is_commit_sha(sha):
        raise HostileResponseError(
            f"{repo_id}@{requested or 'main'}: the Hub at {constants.ENDPOINT} resolved it to {str(sha)[:80]!r}, "
            f"which is not a commit id. Nothing was imported. Check HF_ENDPOINT."
        )
    if is_commit_sha(requested) and sha != requested:
        raise IntegrityError(
            f"{repo_id}@{requested}: the Hub at {constants.ENDPOINT} served commit {sha} instead of the one asked for. "
            f"A commit id names its content, so this endpoint is not serving what you pinned; nothing was imported. "
            f"Check HF_ENDPOINT (and that nothing rewrites the traffic: use https)."
        )


def read_manifest_text(repo_id: str, sha: str, *, token: str | None = None) -> str:
    """The text of ``hub_env.json`` at a commit: from the cache when it is there, else from the Hub.

    Args:
        repo_id: the env repo.
        sha: the commit.
        token: the Hub token (None: huggingface_hub's own).

    Returns:
        The manifest's text (not validated).

    Raises:
        EnvRepoNotFoundError: the commit has no manifest (not an env repo).
    """
    cached = try_to_load_from_cache(repo_id, MANIFEST_FILE, revision=sha, repo_type=REPO_TYPE)
    if isinstance(cached, str) and Path(cached).is_file():
        return Path(cached).read_text(encoding="utf-8")
    text = read_remote_text(repo_id, MANIFEST_FILE, revision=sha, token=token)
    if text is None:
        raise EnvRepoNotFoundError(f"{repo_id}@{sha} has no {MANIFEST_FILE}: it is not an env repo published by push_env.")
    return text


def remote_head(repo_id: str, *, branch: str = "main", token: str | None = None, repo_type: str = REPO_TYPE) -> str | None:
    """The commit a branch points at.

    Args:
        repo_id: the repo.
        branch: the branch (or any revision).
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` (an env repo) or ``"dataset"``.

    Returns:
        The commit sha, or None when the repo does not exist (yet).

    Raises:
        RevisionNotFoundError: the repo has no such branch.
    """
    try:
        with translate_hub_errors(repo_id, branch):
            return api(token).repo_info(repo_id, revision=branch, repo_type=repo_type).sha
    except EnvRepoNotFoundError:
        return None


def repo_private(repo_id: str, *, token: str | None = None, repo_type: str = REPO_TYPE) -> bool | None:
    """Whether a repo is private.

    Args:
        repo_id: the repo.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        True or False; None when it does not exist (or this token cannot see it).
    """
    try:
        with translate_hub_errors(repo_id, None):
            return bool(api(token).repo_info(repo_id, repo_type=repo_type).private)
    except EnvRepoNotFoundError:
        return None


def remote_file_digests(repo_id: str, sha: str, *, token: str | None = None, repo_type: str = REPO_TYPE) -> dict[str, str]:
    """Every file of a commit as the Hub lists it (one request per page of the tree).

    Args:
        repo_id: the repo.
        sha: the commit.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        ``{path: digest}``: ``"sha256:<hex>"`` for an LFS (or Xet) file, ``"git:<blob sha1>"`` for a regular one; compare
        with :func:`local_file_digest` of the same file.
    """
    with translate_hub_errors(repo_id, sha):
        entries = api(token).list_repo_tree(repo_id, revision=sha, recursive=True, repo_type=repo_type)
        out = {}
        for entry in entries:
            lfs = getattr(entry, "lfs", None)
            if getattr(entry, "blob_id", None) is None:
                continue  # a folder
            sha256 = getattr(lfs, "sha256", None) or (lfs.get("sha256") if isinstance(lfs, dict) else None)
            out[entry.path] = f"sha256:{sha256}" if sha256 else f"git:{entry.blob_id}"
    return out


def local_file_digest(path: Path, like: str) -> str:
    """The digest of a local file in the form of a Hub listing's.

    Args:
        path: the file.
        like: a value of :func:`remote_file_digests` (its form: ``sha256:`` or ``git:``).

    Returns:
        ``"sha256:<hex>"`` or ``"git:<blob sha1>"``.
    """
    path = Path(path)
    lfs = like.startswith("sha256:")
    digest = _etag_digest("0" * 64 if lfs else "0" * 40, path.stat().st_size)  # sha256, or git's blob sha1
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return ("sha256:" if lfs else "git:") + digest.hexdigest()


def read_remote_text(
    repo_id: str, path: str, *, revision: str, token: str | None = None, repo_type: str = REPO_TYPE
) -> str | None:
    """The text of one file of a repo at a revision.

    Args:
        repo_id: the repo.
        path: the file's path in the repo.
        revision: a commit, branch or tag.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        The text, or None when the file does not exist there.
    """
    try:
        with translate_hub_errors(repo_id, revision):
            local = hf_hub_download(repo_id, path, revision=revision, repo_type=repo_type, token=token)
    except HubError as e:
        if isinstance(e.__cause__, EntryNotFoundError):
            return None
        raise
    return Path(local).read_text(encoding="utf-8")


def publish_folder(
    folder: Path,
    repo_id: str,
    *,
    parent_commit: str | None,
    remote_files: list[str],
    message: str,
    description: str = "",
    private: bool = False,
    token: str | None = None,
    repo_type: str = REPO_TYPE,
) -> str:
    """Make a repo's content exactly ``folder`` in ONE commit on main.

    Args:
        folder: what the repo is to hold.
        repo_id: the repo (created when it does not exist).
        parent_commit: main as it was read: if main moved since, the Hub refuses the commit and nothing is written.
        remote_files: main's files (those ``folder`` does not hold are deleted, ``.gitattributes`` kept).
        message: the commit's title.
        description: the commit's description.
        private: create the repo private.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        The new commit's sha.

    Raises:
        ConcurrentPushError: main moved since ``parent_commit``.
        HubAccessError, HubError: the Hub refused the commit, or the transfer broke.
    """
    folder = Path(folder)
    local = sorted(str(p.relative_to(folder).as_posix()) for p in folder.rglob("*") if p.is_file())
    ops: list = [CommitOperationAdd(path_in_repo=p, path_or_fileobj=str(folder / p)) for p in local]
    ops += [CommitOperationDelete(path_in_repo=p) for p in sorted(set(remote_files) - set(local)) if p != ".gitattributes"]
    return _commit_to_main(repo_id, ops, parent_commit, message, description, private=private, token=token, repo_type=repo_type)


def update_files(
    repo_id: str, files: dict[str, bytes], *, parent_commit: str, message: str, description: str = "", token: str | None = None
) -> str:
    """Replace some files on main in ONE commit on top of ``parent_commit``, nothing else.

    Args:
        repo_id: the env repo.
        files: ``{path: content}``.
        parent_commit: main as it was read.
        message: the commit's title.
        description: the commit's description.
        token: the Hub token (None: huggingface_hub's own).

    Returns:
        The new commit's sha.

    Raises:
        ConcurrentPushError: main moved since ``parent_commit``.
        HubAccessError, HubError: the Hub refused the commit.
    """
    ops = [CommitOperationAdd(path_in_repo=p, path_or_fileobj=data) for p, data in sorted(files.items())]
    return _commit_to_main(repo_id, ops, parent_commit, message, description, token=token)


def _commit_to_main(
    repo_id: str,
    ops: list,
    parent_commit: str | None,
    message: str,
    description: str,
    *,
    private: bool = False,
    token: str | None = None,
    repo_type: str = REPO_TYPE,
) -> str:
    client = api(token)
    with translate_hub_errors(repo_id, "main"), warnings.catch_warnings():
        # the dataset's parquet files belong in this model-type repo (LeRobot's EnvHub reads model repos)
        warnings.filterwarnings("ignore", message=".*commit a data file.*")
        client.create_repo(repo_id, repo_type=repo_type, private=private, exist_ok=True)
        try:
            # huggingface_hub 1.x takes Xet whenever hf_xet is installed; a Hub without Xet (the
            # loopback server, an air-gapped lab) says so in the repo's xetEnabled: go through LFS then
            with lfs_instead_of_xet(not _xet_enabled(client, repo_id, repo_type)):
                info = client.create_commit(
                    repo_id,
                    operations=ops,
                    commit_message=message,
                    commit_description=description,
                    repo_type=repo_type,
                    parent_commit=parent_commit,
                )
        except HfHubHTTPError as e:
            if getattr(e.response, "status_code", None) != 412:
                raise
            raise ConcurrentPushError(
                f"{repo_id}: main moved away from {parent_commit} while this commit was prepared (another push landed "
                f"first); nothing was written. Re-run push_env: it compares with the new main and commits on top of it."
            ) from e
    return info.oid


def _xet_enabled(client: HfApi, repo_id: str, repo_type: str = REPO_TYPE) -> bool:
    """Whether the repo takes uploads through Xet (``xetEnabled``, as huggingface_hub 0.3x asks it)."""
    info = client.repo_info(repo_id, repo_type=repo_type, expand=["xetEnabled"])  # type: ignore[list-item]
    # 0.x parses it as `xet_enabled`; 1.x keeps the fields it does not know under their JSON names
    return bool(getattr(info, "xet_enabled", None) or getattr(info, "xetEnabled", None))


def tag(
    repo_id: str,
    sha: str,
    name: str,
    *,
    message: str = "",
    token: str | None = None,
    exist_ok: bool = True,
    repo_type: str = REPO_TYPE,
) -> None:
    """Put tag ``name`` on commit ``sha`` (nothing to do when it already names it).

    Args:
        repo_id: the repo.
        sha: the commit.
        name: the tag.
        message: the tag's message.
        token: the Hub token (None: huggingface_hub's own).
        exist_ok: False: a tag that exists, even on ``sha``, is an error.
        repo_type: ``"model"`` or ``"dataset"``.

    Raises:
        HubError: the tag names another commit.
    """
    client = api(token)
    with translate_hub_errors(repo_id, sha):
        try:
            client.create_tag(repo_id, tag=name, revision=sha, tag_message=message, repo_type=repo_type)
        except HfHubHTTPError as e:
            if getattr(e.response, "status_code", None) != 409:
                raise
            # the tag exists: fine if it already names this commit
            refs = client.list_repo_refs(repo_id, repo_type=repo_type)
            current = next((t.target_commit for t in refs.tags if t.name == name), None)
            if current != sha and not exist_ok:
                raise
            if current != sha:
                raise HubError(
                    f"Tag {name!r} of {repo_id} already names commit {current}, not {sha}. Choose another --tag, "
                    f"or delete the old one with HfApi().delete_tag({repo_id!r}, tag={name!r})."
                ) from e


def tag_target(repo_id: str, name: str, *, token: str | None = None, repo_type: str = REPO_TYPE) -> str | None:
    """The commit a tag names.

    Args:
        repo_id: the repo.
        name: the tag.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        The commit sha; None when the repo or the tag does not exist.
    """
    try:
        with translate_hub_errors(repo_id, name):
            refs = api(token).list_repo_refs(repo_id, repo_type=repo_type)
    except EnvRepoNotFoundError:
        return None
    return next((t.target_commit for t in refs.tags if t.name == name), None)


def move_tag(
    repo_id: str, sha: str, name: str, *, message: str = "", token: str | None = None, repo_type: str = REPO_TYPE
) -> None:
    """Make tag ``name`` name commit ``sha``, wherever it pointed before (deleted, then created: as LeRobot's own
    ``LeRobotDataset.push_to_hub`` moves its ``v3.0`` tag; the Hub has no atomic move).

    Args:
        repo_id: the repo.
        sha: the commit.
        name: the tag.
        message: the tag's message.
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.
    """
    target = tag_target(repo_id, name, token=token, repo_type=repo_type)
    if target == sha:
        return
    if target is not None:
        with translate_hub_errors(repo_id, name):
            api(token).delete_tag(repo_id, tag=name, repo_type=repo_type)
    tag(repo_id, sha, name, message=message, token=token, repo_type=repo_type)


def list_remote_files(repo_id: str, sha: str | None, *, token: str | None = None, repo_type: str = REPO_TYPE) -> list[str]:
    """The files of a repo at a commit.

    Args:
        repo_id: the repo.
        sha: the commit (None: no commit yet, no files).
        token: the Hub token (None: huggingface_hub's own).
        repo_type: ``"model"`` or ``"dataset"``.

    Returns:
        Their repo paths.
    """
    if sha is None:
        return []
    with translate_hub_errors(repo_id, sha):
        return api(token).list_repo_files(repo_id, revision=sha, repo_type=repo_type)
