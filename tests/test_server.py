"""The loopback Hub server, driven only through the unmodified ``huggingface_hub`` client
(``HfApi``, ``snapshot_download``, ``hf_hub_download``, ``HfFileSystem``) — plus a few raw HTTP
requests: what the client itself would refuse to send but an attacker would, and the request
formats of the huggingface_hub version not under test (0.x and 1.x differ in places).
"""

from __future__ import annotations

import base64
import hashlib
import http.client
import json
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
import requests
from huggingface_hub import (
    CommitOperationAdd,
    CommitOperationCopy,
    HfApi,
    HfFileSystem,
    constants,
    hf_hub_download,
    snapshot_download,
)
from huggingface_hub.errors import (
    BadRequestError,
    EntryNotFoundError,
    HfHubHTTPError,
    LocalEntryNotFoundError,
    RepositoryNotFoundError,
    RevisionNotFoundError,
)

from hub_envs.testing import HubServer, HubServerError, hub_environment

REPO_TYPES = ["model", "dataset"]


def _add(path: str, data: bytes) -> CommitOperationAdd:
    return CommitOperationAdd(path_in_repo=path, path_or_fileobj=data)


def _commit(api: HfApi, repo_id: str, files: dict[str, bytes], repo_type: str = "model", **kw) -> str:
    ops = [_add(p, d) for p, d in files.items()]
    return api.create_commit(repo_id, ops, commit_message=kw.pop("message", "update"), repo_type=repo_type, **kw).oid


@dataclass
class Namespace:
    """A shared server seen from one test: its own namespace for repo ids and its own HF cache."""

    api: HfApi
    ns: str
    endpoint: str
    hf_home: Path


def _namespace(request) -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]", "-", request.node.name.removeprefix("test_"))
    return re.sub(r"-{2,}", "-", name)[:80].strip("-.")


# Most tests need fresh repos, not a fresh server: they share one (per module) under their own
# namespace, which keeps this file fast. Tests that restart, kill or inspect a server use `hub`.
@pytest.fixture(scope="module")
def _shared_server(tmp_path_factory):
    with HubServer(tmp_path_factory.mktemp("shared") / "hub-data") as server:
        yield server


@pytest.fixture(scope="module")
def _small_pages_server(tmp_path_factory):
    """A server whose tree and commit lists come 3 items per page."""
    with HubServer(tmp_path_factory.mktemp("small-pages") / "hub-data", page_size=3) as server:
        yield server


def _enter(server: HubServer, request, tmp_path: Path):
    with hub_environment(server.endpoint, tmp_path / "hf_home"):
        yield Namespace(HfApi(endpoint=server.endpoint), _namespace(request), server.endpoint, tmp_path / "hf_home")


@pytest.fixture
def shared(_shared_server, request, tmp_path):
    yield from _enter(_shared_server, request, tmp_path)


@pytest.fixture
def small_pages(_small_pages_server, request, tmp_path):
    yield from _enter(_small_pages_server, request, tmp_path)


# --- repos --------------------------------------------------------------------------------------


def test_create_repo_of_each_type_with_exist_ok_and_conflict(shared):
    ns = shared.ns
    api = shared.api
    url = api.create_repo(f"{ns}/env")
    assert url.repo_id == f"{ns}/env" and url.repo_type == "model" and url.endpoint == shared.endpoint
    assert api.create_repo(f"{ns}/data", repo_type="dataset").repo_type == "dataset"
    assert api.create_repo(f"{ns}/demo", repo_type="space", space_sdk="static").repo_type == "space"

    with pytest.raises(HfHubHTTPError) as exc:
        api.create_repo(f"{ns}/env")
    assert exc.value.response.status_code == 409
    assert api.create_repo(f"{ns}/env", exist_ok=True).repo_id == f"{ns}/env"
    # same name, other type: a different repo
    assert api.create_repo(f"{ns}/env", repo_type="dataset").repo_type == "dataset"

    # a new repo has the Hub's initial commit with .gitattributes on main
    info = api.model_info(f"{ns}/env")
    assert len(info.sha) == 40 and [s.rfilename for s in info.siblings] == [".gitattributes"]
    commits = api.list_repo_commits(f"{ns}/env")
    assert [c.title for c in commits] == ["initial commit"] and commits[0].commit_id == info.sha
    assert api.space_info(f"{ns}/demo").sha
    # no namespace: the caller's own
    assert api.create_repo("solo").repo_id == f"{api.whoami(token='any')['name']}/solo"


def test_repo_ids_are_case_insensitive_like_the_hub(shared):
    ns = shared.ns
    shared.api.create_repo(f"{ns.capitalize()}/MyEnv")
    _commit(shared.api, f"{ns}/myenv", {"a.txt": b"a"})
    assert shared.api.model_info(f"{ns.upper()}/myenv").id == f"{ns.capitalize()}/MyEnv"
    assert Path(hf_hub_download(f"{ns}/MYENV", "a.txt")).read_bytes() == b"a"


def test_private_flag_is_kept_reported_and_updatable(shared):
    ns = shared.ns
    shared.api.create_repo(f"{ns}/secret", private=True)
    shared.api.create_repo(f"{ns}/open")
    assert shared.api.model_info(f"{ns}/secret").private is True
    assert shared.api.model_info(f"{ns}/open").private is False
    shared.api.update_repo_settings(f"{ns}/secret", private=False)
    assert shared.api.model_info(f"{ns}/secret").private is False
    assert {m.id for m in shared.api.list_models(author=ns)} == {f"{ns}/secret", f"{ns}/open"}


def test_private_flag_is_understood_as_either_client_version_sends_it(shared):
    # huggingface_hub 0.x sends {"private": bool}, 1.x {"visibility": "public" | "private" | "protected"};
    # the client under test sends only one of them, so both are also sent raw here.
    ns, api = shared.ns, shared.api

    def create(name: str, repo_type: str = "model", **fields) -> requests.Response:
        body = {"name": name, "organization": ns, "type": repo_type, **fields}
        return requests.post(f"{shared.endpoint}/api/repos/create", json=body)

    def settings(name: str, **fields) -> requests.Response:
        return requests.put(f"{shared.endpoint}/api/models/{ns}/{name}/settings", json=fields)

    for name, fields, private in (
        ("old-private", {"private": True}, True),
        ("old-public", {"private": False}, False),
        ("new-private", {"visibility": "private"}, True),
        ("new-public", {"visibility": "public"}, False),
        ("both", {"private": True, "visibility": "private"}, True),
        ("unsaid", {}, False),
    ):
        assert create(name, **fields).status_code == 200, name
        assert api.model_info(f"{ns}/{name}").private is private, name
    assert create("demo", "space", sdk="static", visibility="protected").status_code == 200
    assert api.space_info(f"{ns}/demo").private is True  # no app runs here: its files stay private

    assert settings("old-private", visibility="public").json() == {"private": False}
    assert settings("old-public", private=True).json() == {"private": True}
    assert settings("new-private", gated=False).json() == {"private": True}  # unsaid: unchanged
    for fields in (
        {"visibility": "protected"},
        {"visibility": "secret"},
        {"private": "yes"},
        {"private": True, "visibility": "public"},
    ):
        assert create("refused", **fields).status_code == 400, fields
        assert settings("new-public", **fields).status_code == 400, fields
    assert not api.repo_exists(f"{ns}/refused") and api.model_info(f"{ns}/new-public").private is False


def test_delete_repo(shared):
    ns = shared.ns
    shared.api.create_repo(f"{ns}/gone", repo_type="dataset")
    shared.api.delete_repo(f"{ns}/gone", repo_type="dataset")
    with pytest.raises(RepositoryNotFoundError):
        shared.api.dataset_info(f"{ns}/gone")
    with pytest.raises(RepositoryNotFoundError):
        shared.api.delete_repo(f"{ns}/gone", repo_type="dataset")
    shared.api.delete_repo(f"{ns}/gone", repo_type="dataset", missing_ok=True)
    shared.api.create_repo(f"{ns}/gone", repo_type="dataset")  # the name is free again
    assert shared.api.list_repo_files(f"{ns}/gone", repo_type="dataset") == [".gitattributes"]


def test_whoami(shared, hub_with_token):
    assert shared.api.whoami(token="whatever")["name"] == "local"
    assert hub_with_token.api.whoami()["name"] == "local"
    # 0.x re-raises a 401 here as a plain requests.HTTPError, 1.x as HfHubHTTPError (an httpx.HTTPError)
    with pytest.raises((requests.HTTPError, HfHubHTTPError)) as exc:
        HfApi(endpoint=hub_with_token.endpoint, token="wrong").whoami()
    assert exc.value.response.status_code == 401
    assert exc.value.response.headers["X-Error-Message"] == "Invalid credentials in Authorization header"


# --- uploads and downloads ----------------------------------------------------------------------


def test_upload_folder_then_snapshot_and_file_downloads(shared, tmp_path):
    ns = shared.ns
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        folder = tmp_path / "env"
        files = {"env.py": b"print('hi')\n", "assets/mesh.obj": b"v 0 0 0\n" * 100, "assets/deep/x.bin": bytes(range(256))}
        for rel, data in files.items():
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            (folder / rel).write_bytes(data)
        shared.api.create_repo(f"{ns}/env", repo_type=repo_type)
        info = shared.api.upload_folder(folder_path=folder, repo_id=f"{ns}/env", repo_type=repo_type, commit_message="Add env")
        assert len(info.oid) == 40

        assert sorted(shared.api.list_repo_files(f"{ns}/env", repo_type=repo_type)) == sorted([".gitattributes", *files])
        snapshot = Path(snapshot_download(f"{ns}/env", repo_type=repo_type))
        assert snapshot.name == info.oid and str(shared.hf_home) in str(snapshot)
        for rel, data in files.items():
            assert (snapshot / rel).read_bytes() == data
            assert Path(hf_hub_download(f"{ns}/env", rel, repo_type=repo_type)).read_bytes() == data

        repo = shared.api.repo_info(f"{ns}/env", repo_type=repo_type, files_metadata=True)
        assert repo.sha == info.oid
        siblings = {s.rfilename: s for s in repo.siblings}
        for rel, data in files.items():  # blob ids are git blob sha1s, as on the Hub
            assert siblings[rel].size == len(data)
            if rel.endswith(".bin"):  # in LFS (a *.bin pattern of the default .gitattributes): git holds a pointer
                pointer = f"version https://git-lfs.github.com/spec/v1\noid sha256:{hashlib.sha256(data).hexdigest()}\nsize {len(data)}\n"
                data = pointer.encode()
                assert siblings[rel].lfs.sha256 == pointer.split("sha256:")[1].split()[0]
            else:
                assert siblings[rel].lfs is None
            assert siblings[rel].blob_id == hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()
        assert shared.api.file_exists(f"{ns}/env", "assets/deep/x.bin", repo_type=repo_type)
        assert not shared.api.file_exists(f"{ns}/env", "assets/nope.bin", repo_type=repo_type)
        assert repo.last_modified == shared.api.list_repo_commits(f"{ns}/env", repo_type=repo_type)[0].created_at


def test_pinned_sha_and_tag_still_serve_old_content_after_a_new_commit(shared):
    ns = shared.ns
    api = shared.api
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        api.create_repo(f"{ns}/env", repo_type=repo_type)
        old = _commit(api, f"{ns}/env", {"v.txt": b"one", "keep.txt": b"k"}, repo_type)
        api.create_tag(f"{ns}/env", tag="v1", revision=old, repo_type=repo_type, tag_message="first")
        new = _commit(api, f"{ns}/env", {"v.txt": b"two"}, repo_type)
        assert old != new

        for rev in (old, "v1"):
            assert Path(hf_hub_download(f"{ns}/env", "v.txt", revision=rev, repo_type=repo_type)).read_bytes() == b"one"
            snap = Path(snapshot_download(f"{ns}/env", revision=rev, repo_type=repo_type))
            assert snap.name == old and (snap / "v.txt").read_bytes() == b"one"
        assert Path(hf_hub_download(f"{ns}/env", "v.txt", repo_type=repo_type)).read_bytes() == b"two"
        assert api.repo_info(f"{ns}/env", revision="v1", repo_type=repo_type).sha == old
        fs = HfFileSystem()
        prefix = "datasets/" if repo_type == "dataset" else ""
        assert fs.read_bytes(f"{prefix}{ns}/env@{old}/v.txt") == b"one"


def test_branches_and_tags(shared):
    ns = shared.ns
    api = shared.api
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        api.create_repo(f"{ns}/env", repo_type=repo_type)
        base = _commit(api, f"{ns}/env", {"a.txt": b"a"}, repo_type)
        api.create_branch(f"{ns}/env", branch="dev", repo_type=repo_type)
        on_dev = _commit(api, f"{ns}/env", {"b.txt": b"b"}, repo_type, revision="dev")
        api.create_tag(f"{ns}/env", tag="v1.0", revision="dev", repo_type=repo_type)

        refs = api.list_repo_refs(f"{ns}/env", repo_type=repo_type)
        assert {b.name: b.target_commit for b in refs.branches} == {"main": base, "dev": on_dev}
        assert {t.name: t.target_commit for t in refs.tags} == {"v1.0": on_dev}
        assert refs.branches[0].ref.startswith("refs/heads/") and refs.tags[0].ref == "refs/tags/v1.0"
        assert "b.txt" not in api.list_repo_files(f"{ns}/env", repo_type=repo_type)
        assert "b.txt" in api.list_repo_files(f"{ns}/env", revision="v1.0", repo_type=repo_type)
        assert api.revision_exists(f"{ns}/env", "dev", repo_type=repo_type)

        with pytest.raises(HfHubHTTPError) as exc:
            api.create_tag(f"{ns}/env", tag="v1.0", repo_type=repo_type)
        assert exc.value.response.status_code == 409
        api.create_tag(f"{ns}/env", tag="v1.0", repo_type=repo_type, exist_ok=True)
        with pytest.raises(HfHubHTTPError) as exc:
            api.create_branch(f"{ns}/env", branch="dev", repo_type=repo_type)
        assert exc.value.response.status_code == 409
        api.create_branch(f"{ns}/env", branch="dev", repo_type=repo_type, exist_ok=True)
        api.create_branch(f"{ns}/env", branch="from-sha", revision=base, repo_type=repo_type)
        assert api.repo_info(f"{ns}/env", revision="from-sha", repo_type=repo_type).sha == base

        api.delete_tag(f"{ns}/env", tag="v1.0", repo_type=repo_type)
        api.delete_branch(f"{ns}/env", branch="dev", repo_type=repo_type)
        assert not api.revision_exists(f"{ns}/env", "dev", repo_type=repo_type)
        assert not api.revision_exists(f"{ns}/env", "v1.0", repo_type=repo_type)
        with pytest.raises(RevisionNotFoundError):
            api.delete_tag(f"{ns}/env", tag="v1.0", repo_type=repo_type)
        # the commit outlives its branch: pinned downloads keep working
        assert Path(hf_hub_download(f"{ns}/env", "b.txt", revision=on_dev, repo_type=repo_type)).read_bytes() == b"b"


def test_missing_repo_revision_or_file_raise_the_clients_typed_errors(shared):
    ns = shared.ns
    api = shared.api
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        with pytest.raises(RepositoryNotFoundError):
            api.repo_info(f"{ns}/nope", repo_type=repo_type)
        with pytest.raises(RepositoryNotFoundError):
            hf_hub_download(f"{ns}/nope", "x.txt", repo_type=repo_type)
        with pytest.raises(RepositoryNotFoundError):
            snapshot_download(f"{ns}/nope", repo_type=repo_type)
        with pytest.raises(RepositoryNotFoundError):
            _commit(api, f"{ns}/nope", {"x": b"x"}, repo_type)
        assert not api.repo_exists(f"{ns}/nope", repo_type=repo_type)

        api.create_repo(f"{ns}/env", repo_type=repo_type)
        with pytest.raises(RevisionNotFoundError):
            api.repo_info(f"{ns}/env", revision="no-such-branch", repo_type=repo_type)
        with pytest.raises(RevisionNotFoundError):
            hf_hub_download(f"{ns}/env", ".gitattributes", revision="no-such-branch", repo_type=repo_type)
        with pytest.raises(RevisionNotFoundError):
            snapshot_download(f"{ns}/env", revision="0" * 40, repo_type=repo_type)
        with pytest.raises(RevisionNotFoundError):
            api.list_repo_commits(f"{ns}/env", revision="nope", repo_type=repo_type)
        with pytest.raises(EntryNotFoundError):
            hf_hub_download(f"{ns}/env", "missing.txt", repo_type=repo_type)
        with pytest.raises(EntryNotFoundError):
            list(api.list_repo_tree(f"{ns}/env", path_in_repo="missing", repo_type=repo_type))
        assert not api.file_exists(f"{ns}/env", "missing.txt", repo_type=repo_type)
        assert not api.revision_exists(f"{ns}/env", "nope", repo_type=repo_type)
        with pytest.raises(FileNotFoundError):
            HfFileSystem().info(f"{'datasets/' if repo_type == 'dataset' else ''}{ns}/env/missing.txt")


def test_unusual_file_and_branch_names_round_trip(shared):
    ns = shared.ns
    # the client percent-encodes file paths (keeping "/") and revisions (encoding "/")
    api = shared.api
    api.create_repo(f"{ns}/env", repo_type="dataset")
    names = {"dir with space/ünï cødé #1 %.txt": b"u", "a+b=c&d?.json": b"{}", "x/y/z/deep.txt": b"d"}
    api.create_branch(f"{ns}/env", branch="feature/x", repo_type="dataset")
    sha = _commit(api, f"{ns}/env", names, "dataset", revision="feature/x")
    for rev in ("feature/x", sha):
        for name, data in names.items():
            assert Path(hf_hub_download(f"{ns}/env", name, revision=rev, repo_type="dataset")).read_bytes() == data
    snap = Path(snapshot_download(f"{ns}/env", revision="feature/x", repo_type="dataset"))
    assert (snap / "dir with space" / "ünï cødé #1 %.txt").read_bytes() == b"u"
    tree = {e.path for e in api.list_repo_tree(f"{ns}/env", "dir with space", revision="feature/x", repo_type="dataset")}
    assert tree == {"dir with space/ünï cødé #1 %.txt"}
    assert api.list_repo_commits(f"{ns}/env", revision="feature/x", repo_type="dataset")[0].commit_id == sha
    assert api.list_repo_files(f"{ns}/env", repo_type="dataset") == [".gitattributes"]  # main untouched
    api.delete_branch(f"{ns}/env", branch="feature/x", repo_type="dataset")
    assert not api.revision_exists(f"{ns}/env", "feature/x", repo_type="dataset")


def test_deletions_copies_and_upload_folder_delete_patterns(shared, tmp_path):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/env")
    _commit(api, f"{ns}/env", {"a.txt": b"a", "logs/1.log": b"1", "logs/2.log": b"2", "keep/k.txt": b"k", "old.tmp": b"t"})
    api.delete_file("a.txt", f"{ns}/env")
    api.delete_folder("logs", f"{ns}/env")
    api.create_commit(
        f"{ns}/env",
        [CommitOperationCopy(src_path_in_repo="keep/k.txt", path_in_repo="copied/k.txt")],
        commit_message="copy",
    )
    assert sorted(api.list_repo_files(f"{ns}/env")) == [".gitattributes", "copied/k.txt", "keep/k.txt", "old.tmp"]
    with pytest.raises(EntryNotFoundError):
        api.delete_file("a.txt", f"{ns}/env")
    with pytest.raises(EntryNotFoundError):
        api.delete_folder("logs", f"{ns}/env")

    folder = tmp_path / "up"
    (folder / "new").mkdir(parents=True)
    (folder / "new" / "n.txt").write_bytes(b"n")
    api.upload_folder(folder_path=folder, repo_id=f"{ns}/env", delete_patterns=["*.tmp", "keep/*"])
    assert sorted(api.list_repo_files(f"{ns}/env")) == [".gitattributes", "copied/k.txt", "new/n.txt"]

    # a file and a folder cannot share a name
    with pytest.raises(BadRequestError):
        _commit(api, f"{ns}/env", {"new/n.txt/inner": b"x"})


def test_identical_content_makes_no_commit_like_the_hub(shared):
    ns = shared.ns
    # huggingface_hub compares the preupload `oid` with the local sha1 and skips no-op commits.
    api = shared.api
    api.create_repo(f"{ns}/env")
    head = _commit(api, f"{ns}/env", {"a.txt": b"same", "b.txt": b"b"})
    again = _commit(api, f"{ns}/env", {"a.txt": b"same"})
    empty = api.create_commit(f"{ns}/env", [], commit_message="nothing").oid
    assert again == empty == head
    assert len(api.list_repo_commits(f"{ns}/env")) == 2
    assert _commit(api, f"{ns}/env", {"a.txt": b"changed", "b.txt": b"b"}) != head  # partial change: commits
    assert len(api.list_repo_commits(f"{ns}/env")) == 3


def test_readme_metadata_is_validated_and_reported_as_card_data(shared):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/env")
    _commit(api, f"{ns}/env", {"README.md": b"---\nlicense: mit\ntags:\n- robotics\n---\n# Env\n"})
    info = api.model_info(f"{ns}/env")
    assert info.card_data["license"] == "mit" and info.tags == ["robotics"]
    with pytest.raises(ValueError, match="Invalid metadata in README.md"):
        _commit(api, f"{ns}/env", {"README.md": b"---\ntags: [unclosed\n---\n"})
    with pytest.warns(UserWarning, match="empty or missing yaml metadata"):
        _commit(api, f"{ns}/env", {"README.md": b"# no metadata\n"})


# --- concurrency and crashes --------------------------------------------------------------------


def test_stale_parent_commit_is_refused_with_412(shared):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/env")
    parent = api.model_info(f"{ns}/env").sha
    _commit(api, f"{ns}/env", {"a.txt": b"a"})
    with pytest.raises(HfHubHTTPError) as exc:
        _commit(api, f"{ns}/env", {"b.txt": b"b"}, parent_commit=parent)
    assert exc.value.response.status_code == 412
    assert "The branch was updated since you opened this page" in str(exc.value)
    head = api.model_info(f"{ns}/env").sha
    assert _commit(api, f"{ns}/env", {"b.txt": b"b"}, parent_commit=head) != head


def test_racing_commits_on_the_same_parent_leave_one_winner(shared):
    ns = shared.ns
    api = shared.api
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        api.create_repo(f"{ns}/env", repo_type=repo_type)
        parent = api.repo_info(f"{ns}/env", repo_type=repo_type).sha
        n = 8
        barrier = threading.Barrier(n)
        results: dict[int, object] = {}

        def worker(i: int, barrier=barrier, results=results, repo_type=repo_type, parent=parent) -> None:
            barrier.wait()
            try:
                results[i] = _commit(api, f"{ns}/env", {f"f{i}.txt": b"x" * (1000 + i)}, repo_type, parent_commit=parent)
            except HfHubHTTPError as exc:
                results[i] = exc

        threads = [threading.Thread(target=worker, args=(i,)) for i in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

        winners = {i: r for i, r in results.items() if isinstance(r, str)}
        losers = [r for r in results.values() if not isinstance(r, str)]
        assert len(winners) == 1 and len(losers) == n - 1
        assert all(err.response.status_code == 412 for err in losers)
        ((i, sha),) = winners.items()
        commits = api.list_repo_commits(f"{ns}/env", repo_type=repo_type)
        assert [c.commit_id for c in commits] == [sha, parent]
        assert sorted(api.list_repo_files(f"{ns}/env", repo_type=repo_type)) == [".gitattributes", f"f{i}.txt"]
        snap = Path(snapshot_download(f"{ns}/env", repo_type=repo_type))
        assert (snap / f"f{i}.txt").read_bytes() == b"x" * (1000 + i)


def test_concurrent_commits_without_parent_all_land(shared):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/env")
    n = 8
    barrier = threading.Barrier(n)
    errors: list[Exception] = []

    def worker(i: int) -> None:
        barrier.wait()
        try:
            _commit(api, f"{ns}/env", {f"f{i}.txt": str(i).encode()}, message=f"add {i}")
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(api.list_repo_files(f"{ns}/env")) == n + 1
    assert len(api.list_repo_commits(f"{ns}/env")) == n + 1  # linear history, nothing lost


def test_restarted_server_serves_the_same_repos(hub, tmp_path):
    api = hub.api
    api.create_repo("alice/env", private=True)
    api.create_repo("alice/data", repo_type="dataset")
    sha = _commit(api, "alice/env", {"a.txt": b"persisted"})
    _commit(api, "alice/data", {"d.csv": b"1,2\n"}, "dataset")
    api.create_tag("alice/env", tag="v1")

    hub.server.restart()
    assert hub.server.endpoint == hub.endpoint  # same port
    with hub_environment(hub.endpoint, tmp_path / "fresh_cache"):
        assert Path(hf_hub_download("alice/env", "a.txt", revision="v1")).read_bytes() == b"persisted"
        assert Path(hf_hub_download("alice/data", "d.csv", repo_type="dataset")).read_bytes() == b"1,2\n"
    assert api.model_info("alice/env").sha == sha and api.model_info("alice/env").private is True
    assert _commit(api, "alice/env", {"b.txt": b"b"}) != sha  # and takes new commits


def test_server_killed_mid_commit_leaves_the_repo_at_its_previous_commit(hub):
    api = hub.api
    api.create_repo("alice/env")
    before = _commit(api, "alice/env", {"small.txt": b"s"})
    big = bytes(range(256)) * 4096  # 1 MiB
    big_sha256 = hashlib.sha256(big).hexdigest()
    release = threading.Event()

    def body():  # a commit whose upload stalls after its first file, as a slow client's would
        yield json.dumps({"key": "header", "value": {"summary": "interrupted"}}).encode() + b"\n"
        line = {"key": "file", "value": {"path": "big.bin", "content": base64.b64encode(big).decode(), "encoding": "base64"}}
        yield json.dumps(line).encode() + b"\n"
        release.wait(10)
        yield b'{"key": "deletedFile", "value": {"path": "small.txt"}}\n'

    url = f"{hub.endpoint}/api/models/alice/env/commit/main"
    thread = threading.Thread(target=lambda: _swallow(requests.post, url, data=body()))
    thread.start()
    deadline = time.monotonic() + 10
    while not list(hub.root.rglob(big_sha256)) and time.monotonic() < deadline:  # the first blob is on disk
        time.sleep(0.01)
    assert list(hub.root.rglob(big_sha256)), "the server never stored the first file of the commit"
    hub.server.kill()  # SIGKILL mid-commit
    release.set()
    thread.join()

    hub.server.start()
    assert api.model_info("alice/env").sha == before
    assert [c.commit_id for c in api.list_repo_commits("alice/env")][0] == before
    assert sorted(api.list_repo_files("alice/env")) == [".gitattributes", "small.txt"]
    assert Path(hf_hub_download("alice/env", "small.txt")).read_bytes() == b"s"
    assert _commit(api, "alice/env", {"big.bin": big}, parent_commit=before) != before  # and the repo takes commits


def test_server_killed_around_a_client_commit_keeps_the_repo_consistent(hub):
    api = hub.api
    api.create_repo("alice/env")
    before = _commit(api, "alice/env", {"small.txt": b"s"})
    big = bytes(range(256)) * (40 * 1024)  # 10 MiB
    thread = threading.Thread(target=lambda: _swallow(_commit, api, "alice/env", {"big.bin": big, "small.txt": b"t"}))
    thread.start()
    time.sleep(0.1)
    hub.server.kill()
    thread.join()
    hub.server.start()

    head = api.model_info("alice/env").sha
    files = {p: Path(hf_hub_download("alice/env", p, revision=head)).read_bytes() for p in api.list_repo_files("alice/env")}
    if head == before:  # killed before the branch moved: none of the new commit is visible
        assert set(files) == {".gitattributes", "small.txt"} and files["small.txt"] == b"s"
    else:  # the commit completed first: all of it is visible
        assert files["big.bin"] == big and files["small.txt"] == b"t"


def _swallow(fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except Exception as err:  # the connection dies with the server: expected
        return err


# --- listing and paging -------------------------------------------------------------------------


def test_list_repo_commits_newest_first_across_pages(small_pages):
    api, ns = small_pages.api, small_pages.ns
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        api.create_repo(f"{ns}/env", repo_type=repo_type)
        shas = [_commit(api, f"{ns}/env", {"n.txt": str(i).encode()}, repo_type, message=f"step {i}") for i in range(7)]
        commits = api.list_repo_commits(f"{ns}/env", repo_type=repo_type)  # 8 commits, 3 per page
        assert [c.commit_id for c in commits[:7]] == shas[::-1]
        assert [c.title for c in commits] == [f"step {i}" for i in range(6, -1, -1)] + ["initial commit"]
        assert all(a.created_at >= b.created_at for a, b in zip(commits, commits[1:]))
        assert commits[0].authors == ["local"]
        formatted = api.list_repo_commits(f"{ns}/env", repo_type=repo_type, formatted=True)
        assert formatted[0].formatted_title == "step 6"


def test_tree_is_paged_recursive_and_expandable(small_pages):
    api, ns = small_pages.api, small_pages.ns
    for repo_type in REPO_TYPES:  # dataset repos behave the same
        api.create_repo(f"{ns}/env", repo_type=repo_type)
        files = {f"top{i}.txt": b"t" for i in range(4)} | {f"d/sub{i}.txt": b"s" for i in range(4)} | {"d/e/deep.txt": b"x"}
        first = _commit(api, f"{ns}/env", files, repo_type, message="many files")
        last = _commit(api, f"{ns}/env", {"d/e/deep.txt": b"changed"}, repo_type, message="touch deep")

        everything = list(api.list_repo_tree(f"{ns}/env", recursive=True, repo_type=repo_type))
        assert sorted(e.path for e in everything) == sorted([".gitattributes", *files, "d", "d/e"])
        assert sorted(api.list_repo_files(f"{ns}/env", repo_type=repo_type)) == sorted([".gitattributes", *files])
        top = {e.path: type(e).__name__ for e in api.list_repo_tree(f"{ns}/env", repo_type=repo_type)}
        assert top == {".gitattributes": "RepoFile", "d": "RepoFolder", **{f"top{i}.txt": "RepoFile" for i in range(4)}}
        assert {e.path for e in api.list_repo_tree(f"{ns}/env", "d", repo_type=repo_type)} == {
            "d/e",
            *(f"d/sub{i}.txt" for i in range(4)),
        }
        api.create_branch(f"{ns}/env", branch="feature/x", repo_type=repo_type)  # an encoded "/" in paged URLs
        in_d = {e.path for e in api.list_repo_tree(f"{ns}/env", "d", recursive=True, revision="feature/x", repo_type=repo_type)}
        assert in_d == {"d/e", "d/e/deep.txt", *(f"d/sub{i}.txt" for i in range(4))}
        assert len(api.list_repo_commits(f"{ns}/env", revision="feature/x", repo_type=repo_type)) == 3
        expanded = {e.path: e for e in api.list_repo_tree(f"{ns}/env", "d", expand=True, repo_type=repo_type)}
        assert expanded["d/sub0.txt"].last_commit.oid == first
        assert expanded["d/e"].last_commit.oid == last and expanded["d/e"].last_commit.title == "touch deep"


def test_get_paths_info(shared):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/env")
    sha = _commit(api, f"{ns}/env", {"a.txt": b"abc", "d/b.txt": b"b"})
    infos = {i.path: i for i in api.get_paths_info(f"{ns}/env", ["a.txt", "d", "missing"], expand=True)}
    assert set(infos) == {"a.txt", "d"}
    assert infos["a.txt"].size == 3 and infos["a.txt"].last_commit.oid == sha
    assert len(infos["d"].tree_id) == 40


def test_hf_file_system_ls_info_glob_and_partial_reads(shared):
    ns = shared.ns
    api = shared.api
    api.create_repo(f"{ns}/data", repo_type="dataset")
    payload = bytes(i % 251 for i in range(200_000))
    _commit(api, f"{ns}/data", {"data/big.bin": payload, "data/x.csv": b"a,b\n", "README.md": b"---\nx: 1\n---\n"}, "dataset")
    fs = HfFileSystem()
    assert set(fs.ls(f"datasets/{ns}/data/data", detail=False)) == {
        f"datasets/{ns}/data/data/big.bin",
        f"datasets/{ns}/data/data/x.csv",
    }
    assert fs.info(f"datasets/{ns}/data/data/big.bin")["size"] == len(payload)
    assert fs.glob(f"datasets/{ns}/data/**/*.csv") == [f"datasets/{ns}/data/data/x.csv"]
    # small blocks: each read below is a Range request; a server ignoring Range would return wrong bytes
    with fs.open(f"datasets/{ns}/data/data/big.bin", block_size=1024) as f:
        f.seek(123_456)
        assert f.read(100) == payload[123_456:123_556]
        f.seek(-10, 2)
        assert f.read() == payload[-10:]
    assert fs.cat_file(f"datasets/{ns}/data/data/big.bin", start=10, end=20) == payload[10:20]


# --- access control -----------------------------------------------------------------------------


def test_server_with_token_refuses_writes_without_it(hub_with_token):
    hub = hub_with_token
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    with pytest.raises(HfHubHTTPError) as exc:
        anonymous.create_repo("alice/env")
    assert exc.value.response.status_code == 401 and "HF_TOKEN" in str(exc.value)

    hub.api.create_repo("alice/env")  # HF_TOKEN is set by the fixture
    sha = _commit(hub.api, "alice/env", {"a.txt": b"a"})
    for write in (
        lambda: _commit(anonymous, "alice/env", {"b.txt": b"b"}),
        lambda: anonymous.create_tag("alice/env", tag="v1"),
        lambda: anonymous.create_branch("alice/env", branch="dev"),
        lambda: anonymous.delete_repo("alice/env"),
        lambda: anonymous.update_repo_settings("alice/env", private=True),
    ):
        with pytest.raises(HfHubHTTPError) as exc:
            write()
        assert exc.value.response.status_code == 401
    # public reads stay open
    assert anonymous.model_info("alice/env").sha == sha
    assert Path(hf_hub_download("alice/env", "a.txt", token=False)).read_bytes() == b"a"
    with pytest.raises(HfHubHTTPError) as exc:
        HfApi(endpoint=hub.endpoint, token="wrong").create_repo("alice/other")
    assert exc.value.response.status_code == 401


def test_private_repos_need_the_token_for_reads_too(hub_with_token, tmp_path):
    hub = hub_with_token
    hub.api.create_repo("alice/secret", private=True)
    _commit(hub.api, "alice/secret", {"s.txt": b"s"})
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    with pytest.raises(RepositoryNotFoundError):
        anonymous.model_info("alice/secret")
    with pytest.raises(RepositoryNotFoundError):
        anonymous.list_repo_files("alice/secret")
    with hub_environment(hub.endpoint, tmp_path / "anon_home", token=None):
        with pytest.raises(RepositoryNotFoundError):
            hf_hub_download("alice/secret", "s.txt")
        assert "alice/secret" not in {m.id for m in HfApi(endpoint=hub.endpoint).list_models()}
    assert Path(hf_hub_download("alice/secret", "s.txt")).read_bytes() == b"s"


# --- paths that escape the repo -----------------------------------------------------------------


def _raw_commit(endpoint: str, repo_id: str, path: str) -> requests.Response:
    lines = [
        {"key": "header", "value": {"summary": "evil", "description": ""}},
        {"key": "file", "value": {"path": path, "content": base64.b64encode(b"pwned").decode(), "encoding": "base64"}},
    ]
    body = b"".join(json.dumps(line).encode() + b"\n" for line in lines)
    return requests.post(
        f"{endpoint}/api/models/{repo_id}/commit/main", data=body, headers={"Content-Type": "application/x-ndjson"}
    )


def _files_under(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*") if p.is_file()}


def test_paths_escaping_the_repo_are_refused(hub, tmp_path):
    api = hub.api
    api.create_repo("alice/env")
    head = _commit(api, "alice/env", {"ok.txt": b"ok"})
    before = _files_under(tmp_path) - _files_under(hub.hf_home)

    with pytest.raises(ValueError):  # the client refuses the obvious one itself
        _commit(api, "alice/env", {"../x": b"x"})
    # Through the client, each of these is refused: by the server (400), or by the client before it
    # sends anything (huggingface_hub >= 1.0 rejects a ".." segment anywhere; 0.x only a leading one).
    # Either way the server must refuse it too, so it is also sent raw.
    for path in ("a/../../evil.txt", "a\\..\\evil.txt", "sub/./evil.txt"):
        try:
            operation = _add(path, b"pwned")
        except ValueError as err:  # refused by the client
            assert ".." in path.split("/") and "Invalid `path_in_repo`" in str(err), (path, err)
        else:
            with pytest.raises(BadRequestError):
                api.create_commit("alice/env", [operation], commit_message="evil")
        response = _raw_commit(hub.endpoint, "alice/env", path)
        assert response.status_code == 400, (path, response.text)
    for path in ("../evil.txt", "/etc/evil.txt", "a/../../../evil.txt", "a//evil", "a\x00b", ".git/config", ".."):
        response = _raw_commit(hub.endpoint, "alice/env", path)
        assert response.status_code == 400, (path, response.text)

    for url_path in (
        "/alice/env/resolve/main/%2e%2e/%2e%2e/%2e%2e/FORMAT",
        "/alice/env/resolve/main/..%2F..%2F..%2FFORMAT",
        "/alice/env/resolve/main/%2E%2E%5C%2E%2E%5Crepo.json",
        "/alice/env/resolve/main/ok.txt%00.png",
        "/alice/env/resolve/main/%2Fetc%2Fpasswd",
        "/api/models/alice/env/tree/main/..%2F..",
    ):
        for method in ("GET", "HEAD"):
            response = requests.request(method, hub.endpoint + url_path)
            assert response.status_code == 400, (method, url_path, response.status_code)
            assert b"hub-envs-store" not in response.content and b"root:" not in response.content
    # literal dot segments, which `requests` would normalize away before sending
    host, port = hub.endpoint.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    conn.request("GET", "/alice/env/resolve/main/../../../FORMAT")
    response = conn.getresponse()
    assert response.status == 400 and b"hub-envs-store" not in response.read()
    conn.close()

    assert api.model_info("alice/env").sha == head  # nothing was committed
    assert api.list_repo_files("alice/env") == [".gitattributes", "ok.txt"]
    after = _files_under(tmp_path) - _files_under(hub.hf_home)
    assert not any("evil" in p.name for p in after)
    assert {p for p in after - before if "hub-data" not in p.parts} == set()  # nothing written outside the store


# --- the test helpers themselves ----------------------------------------------------------------


def test_hub_environment_switches_servers_and_caches_then_restores_everything(hub, tmp_path):
    hub.api.create_repo("alice/env")
    _commit(hub.api, "alice/env", {"a.txt": b"from the first server"})
    outer = (constants.ENDPOINT, constants.HF_HUB_CACHE, constants.HF_HUB_OFFLINE, os.environ.get("HF_ENDPOINT"))
    with HubServer(tmp_path / "second-data") as second:
        with hub_environment(second.endpoint, tmp_path / "second_home"):
            HfApi().create_repo("alice/env")  # the default endpoint is the second server now
            _commit(HfApi(), "alice/env", {"a.txt": b"from the second server"})
            path = Path(hf_hub_download("alice/env", "a.txt"))
            assert path.read_bytes() == b"from the second server"
            assert str(tmp_path / "second_home") in str(path)
        assert (constants.ENDPOINT, constants.HF_HUB_CACHE, constants.HF_HUB_OFFLINE, os.environ.get("HF_ENDPOINT")) == outer
    assert Path(hf_hub_download("alice/env", "a.txt")).read_bytes() == b"from the first server"

    # offline: what is cached still resolves, nothing else does
    with hub_environment(hub.endpoint, hub.hf_home, offline=True):
        assert Path(hf_hub_download("alice/env", "a.txt")).read_bytes() == b"from the first server"
        with pytest.raises(LocalEntryNotFoundError):
            hf_hub_download("alice/env", ".gitattributes")
    assert constants.HF_HUB_OFFLINE is False


def test_hub_server_reports_why_it_could_not_start(hub, tmp_path):
    with pytest.raises(HubServerError, match="in use by another hub-envs server"):
        HubServer(hub.root, startup_timeout=20)  # one server per root
    assert list(hub.api.list_models()) == []  # and the first one is unharmed

    not_a_store = tmp_path / "home"
    not_a_store.mkdir()
    (not_a_store / "precious.txt").write_text("keep me")
    with pytest.raises(HubServerError, match="not a hub-envs store"):
        HubServer(not_a_store, startup_timeout=20)
    assert (not_a_store / "precious.txt").read_text() == "keep me"
