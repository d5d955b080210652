"""Faults and concurrency against the real loopback server, through the unmodified client.

Faults are injected into the server itself (``HUB_ENVS_SERVER_FAULTS``, see
:mod:`hub_envs.server.faults`): 500 answers, a connection dropped mid-file, the server process
dying in the middle of a push. What huggingface_hub does about them, on 0.35 (requests) and 1.x (httpx):

``load_env`` fetches an env's small files with one ``GET`` each into huggingface_hub's cache
(``hub_io._get_into_cache``); any answer out of the ordinary there (a 5xx, a body cut off) makes it
ask ``hf_hub_download``, whose behaviour follows. Larger files and the dataset's data go through
``hf_hub_download`` / ``snapshot_download`` directly.

* A 5xx on a file's metadata ``HEAD .../resolve/...`` is retried by both. 0.35 sends every HEAD
  through ``http_backoff`` (500/502/503/504 and connection errors, up to 5 retries, sleeping 1, 2,
  4, 8, 8 s); 1.x sends the first HEAD without retries and, when it fails with a retryable error
  and the file is not cached, asks again through ``http_backoff`` (408/429/5xx, same schedule).
* A 5xx on a file's content ``GET .../resolve/...`` is retried by 0.35 (``http_backoff`` again) but
  not by 1.x (``http_get`` retries only 408 and 429): the load fails, with an error that says to retry.
* A body cut off mid-file is neither retried nor resumed by 0.35 (``http_get`` raises
  ``ChunkedEncodingError``); 1.x resumes it (a ``Range`` request, up to 5 times, 1 s apart), then
  raises ``httpx.RemoteProtocolError``. Either way the next load completes the same cache.
* API calls (``repo_info``, ``create_commit``) are not retried by either. A server killed while it
  reads a commit resets the connection: ``requests.ConnectionError`` / ``httpx.ReadError``.

hub-envs turns each failure into a typed error (``cannot reach the Hub``, ``broke off``,
``answered 5xx``, each with a next step) and never treats a partial snapshot as a good one.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import traceback
from pathlib import Path

import gymnasium as gym
import pytest
from helpers import TINY, copy_env
from huggingface_hub import HfApi, hf_hub_download, scan_cache_dir
from huggingface_hub import constants as hf_constants

from hub_envs import _compat, errors, load_env, push_env
from hub_envs.testing import HubServer, hub_environment


class FaultyHub:
    """A server started with ``HUB_ENVS_SERVER_FAULTS`` pointing at a rules file tests rewrite."""

    def __init__(self, root: Path):
        self.rules = root / "faults.json"
        self.rules.write_text("[]")
        self.server = HubServer(root / "hub-data", env={"HUB_ENVS_SERVER_FAULTS": str(self.rules)})
        self.endpoint = self.server.endpoint
        self.api = HfApi(endpoint=self.endpoint)

    def inject(self, *rules: dict) -> None:
        self.rules.write_text(json.dumps(list(rules)))

    def heal(self) -> None:
        self.rules.write_text("[]")

    def injected(self) -> int:
        return self.server.output().count("injected fault")


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    root = tmp_path_factory.mktemp("faulty")
    hub = FaultyHub(root)
    try:
        with hub_environment(hub.endpoint, root / "pusher-home"):
            hub.sha = push_env(TINY, "flt/base", episodes=2, progress=False).sha
        yield hub
    finally:
        hub.server.stop()
        hub.server.remove_log()


def _incomplete(home: Path) -> list[Path]:
    return list((home / "hub").rglob("*.incomplete")) if (home / "hub").is_dir() else []


def test_a_cold_load_asks_once_per_file_and_the_cache_is_huggingface_hubs_own(faulty, tmp_path):
    # load_env fetches an env's small files with one GET each (no metadata HEAD first): with every HEAD failing
    # the load succeeds and not one fault is injected
    home, ref = tmp_path / "home", f"flt/base@{faulty.sha}"
    before = faulty.injected()
    faulty.inject({"match": rf"HEAD /flt/base/resolve/{faulty.sha}/", "times": -1})
    try:
        with hub_environment(faulty.endpoint, home):
            loaded = load_env(ref, trust_remote_code=True)
            assert loaded.report.features.ok and "matches" in loaded.report.fingerprint
            loaded.unregister()
    finally:
        faulty.heal()
    assert faulty.injected() == before
    # laid out as huggingface_hub lays it out: its own reader and scan_cache_dir find every file, offline too
    with hub_environment(faulty.endpoint, home, offline=True):
        for rel in loaded.manifest.files:
            if (loaded.path / rel).is_file():
                local = hf_hub_download("flt/base", rel, revision=faulty.sha)
                assert Path(local) == loaded.path / rel and Path(local).is_symlink()
        (repo,) = scan_cache_dir(home / "hub").repos
        (revision,) = repo.revisions
        assert revision.commit_hash == faulty.sha
        assert {f.file_path for f in revision.files} == {p for p in loaded.path.rglob("*") if p.is_file()}
        again = load_env(ref, trust_remote_code=True)
        assert again.report.integrity.endswith("match the manifest")
        again.unregister()
    # the files fetched later (the dataset's data, through snapshot_download) still ask HEAD first: a 5xx there is
    # retried by both client versions (0.x sends every HEAD through http_backoff; 1.x asks again through it)
    before = faulty.injected()
    faulty.inject({"match": rf"HEAD /flt/base/resolve/{faulty.sha}/dataset/data/", "times": 3})
    try:
        with hub_environment(faulty.endpoint, home):
            assert loaded.open_dataset().num_frames == loaded.manifest.dataset["frames"]
    finally:
        faulty.heal()
    assert faulty.injected() - before == 3  # three HEADs failed, and huggingface_hub asked again each time


@pytest.mark.skipif(
    not hasattr(hf_constants, "HF_HUB_DISABLE_SYMLINKS"), reason="huggingface_hub 0.x has no HF_HUB_DISABLE_SYMLINKS"
)
def test_with_symlinks_disabled_a_load_keeps_files_not_links(faulty, tmp_path, monkeypatch):
    monkeypatch.setattr(hf_constants, "HF_HUB_DISABLE_SYMLINKS", True)  # as HF_HUB_DISABLE_SYMLINKS=1 sets it
    with hub_environment(faulty.endpoint, tmp_path / "home"):
        loaded = load_env(f"flt/base@{faulty.sha}", trust_remote_code=True)
        loaded.unregister()
    files = [p for p in loaded.path.rglob("*") if not p.is_dir()]
    assert files and not [p for p in files if p.is_symlink()]


def test_transient_500s_on_file_contents_are_retried_by_0x_and_a_clear_error_on_1x(faulty, tmp_path):
    home = tmp_path / "home"
    ref = f"flt/base@{faulty.sha}"
    before = faulty.injected()
    faulty.inject({"match": rf"GET /flt/base/resolve/{faulty.sha}/(env\.py|dataset/meta/)", "times": 3})
    try:
        with hub_environment(faulty.endpoint, home):
            if _compat.file_get_retries_server_errors():  # huggingface_hub 0.x: retried, the load succeeds
                loaded = load_env(ref, trust_remote_code=True)
                assert loaded.report.features.ok and "matches" in loaded.report.fingerprint
                loaded.unregister()
                assert faulty.injected() - before == 3  # three GETs failed, and huggingface_hub retried each
            else:  # huggingface_hub 1.x: not retried, the load fails and says to retry
                with pytest.raises(errors.HubError) as e:
                    load_env(ref, trust_remote_code=True)
                assert ref in str(e.value) and "answered 500" in str(e.value) and "Retry" in str(e.value)
                assert faulty.injected() - before >= 1
                # the partial snapshot is not a usable one (1.x cancels the downloads not yet started when
                # one fails, so the manifest itself may be missing: then the snapshot is not cached at all)
                with hub_environment(faulty.endpoint, home, offline=True):
                    with pytest.raises(errors.OfflineNotCachedError, match="(only partly|is not) in the local cache"):
                        load_env(ref, trust_remote_code=True)
    finally:
        faulty.heal()
    with hub_environment(faulty.endpoint, home):  # loaded again (1.x: retried as the error says), the cache verifies
        loaded = load_env(ref, trust_remote_code=True)
        assert loaded.report.integrity.endswith("match the manifest") and loaded.report.features.ok
        loaded.unregister()
    assert _incomplete(home) == []


def test_transient_500s_on_dataset_files_fail_the_fetch_clearly_and_the_next_one_completes(faulty, tmp_path):
    # load_env does not fetch the dataset's data files: opening the dataset does
    home = tmp_path / "home"
    ref = f"flt/base@{faulty.sha}"
    with hub_environment(faulty.endpoint, home):
        loaded = load_env(ref, trust_remote_code=True)
        loaded.unregister()
        assert not list(loaded.path.glob("dataset/data/**/*.parquet"))
        before = faulty.injected()
        faulty.inject({"match": rf"GET /flt/base/resolve/{faulty.sha}/dataset/data/", "times": 3})
        try:
            if _compat.file_get_retries_server_errors():  # 0.x: retried, the fetch succeeds
                assert loaded.fetch_dataset() == loaded.path / "dataset"
                assert faulty.injected() - before == 3
            else:  # 1.x: not retried: a typed error that says to retry; offline, opening says what is missing
                with pytest.raises(errors.HubError) as e:
                    loaded.fetch_dataset()
                assert ref in str(e.value) and "answered 500" in str(e.value) and "Retry" in str(e.value)
                with hub_environment(faulty.endpoint, home, offline=True):
                    with pytest.raises(errors.DatasetNotCachedError, match="not in the local cache"):
                        loaded.open_dataset()
        finally:
            faulty.heal()
        assert loaded.open_dataset().num_frames == loaded.manifest.dataset["frames"]
    assert _incomplete(home) == []


def test_a_failing_hub_api_is_a_clear_error_and_the_next_load_succeeds(faulty, tmp_path):
    faulty.inject({"match": r"GET /api/models/flt/base/revision/", "times": -1, "status": 503})
    home = tmp_path / "home"
    with hub_environment(faulty.endpoint, home):
        try:
            with pytest.raises(errors.HubError) as e:
                load_env("flt/base@main", trust_remote_code=True)
        finally:
            faulty.heal()
        assert "flt/base@main" in str(e.value) and "answered 503" in str(e.value) and "Retry" in str(e.value)
        assert not list((home / "hub").glob("models--flt--base/snapshots/*"))  # nothing half-fetched
        with pytest.warns(UserWarning, match=faulty.sha):
            load_env("flt/base@main", trust_remote_code=True).unregister()


def test_a_connection_dropped_mid_file_fails_clearly_and_leaves_no_usable_partial_snapshot(faulty, tmp_path):
    home = tmp_path / "home"
    ref = f"flt/base@{faulty.sha}"
    faulty.inject(
        {"match": rf"GET /flt/base/resolve/{faulty.sha}/dataset/meta/", "action": "drop", "after_bytes": 64, "times": -1}
    )
    try:
        with hub_environment(faulty.endpoint, home):
            with pytest.raises(errors.HubError) as e:
                load_env(ref, trust_remote_code=True)
            assert ref in str(e.value) and "broke off" in str(e.value) and "Retry" in str(e.value)
            with hub_environment(faulty.endpoint, home, offline=True):  # the partial snapshot is not a usable one
                with pytest.raises(errors.OfflineNotCachedError, match="only partly in the local cache"):
                    load_env(ref, trust_remote_code=True)
    finally:
        faulty.heal()
    with hub_environment(faulty.endpoint, home):  # the network heals: the same cache completes and verifies
        loaded = load_env(ref, trust_remote_code=True)
        assert loaded.report.integrity.endswith("match the manifest") and loaded.report.features.ok
        assert loaded.open_dataset().num_frames == loaded.manifest.dataset["frames"]
        loaded.unregister()
    assert _incomplete(home) == []


@pytest.mark.parametrize(
    "repo, during",
    [
        ("flt/killed", "PUT /flt/killed.git/info/lfs/objects/upload/"),  # the dataset's bytes, through LFS
        ("flt/killed2", "POST /api/models/flt/killed2/commit/"),  # the commit that names them
    ],
    ids=["lfs-upload", "commit"],
)
def test_a_server_killed_during_a_push_leaves_no_partial_commit_and_a_rerun_completes(faulty, tmp_path, repo, during):
    faulty.inject({"match": during, "action": "exit", "after_bytes": 1024})
    with hub_environment(faulty.endpoint, tmp_path / "home"):
        try:
            with pytest.raises(errors.HubError) as e:
                push_env(TINY, repo, episodes=2, progress=False)
            assert not faulty.server.running  # the fault killed the server mid-upload
        finally:  # whatever happened, the module's later tests need the server back
            faulty.heal()
            faulty.server.start()  # same root, same port; no-op if it still runs
        # a connection reset mid-request (requests' ConnectionError, httpx's ReadError or WriteError), or, when
        # the whole (small) body was sent, a connection closed without an answer (httpx's RemoteProtocolError)
        # (1.x closes its client after a network error: other LFS upload threads then fail with "client has been closed")
        cause = e.value.__cause__
        assert isinstance(cause, _compat.NETWORK_ERRORS + _compat.TRANSFER_ERRORS) or "closed" in str(cause.__cause__), repr(
            cause
        )
        assert repo in str(e.value) and any(s in str(e.value) for s in ("cannot reach the Hub", "broke off", "broke during"))
        commits = faulty.api.list_repo_commits(repo)
        assert len(commits) == 1 and faulty.api.list_repo_files(repo) == [".gitattributes"]  # only create_repo's

        result = push_env(TINY, repo, episodes=2, progress=False)
        assert result.created_commit
        loaded = load_env(f"{repo}@{result.sha}", trust_remote_code=True)
        assert loaded.report.features.ok
        loaded.unregister()


# --- concurrency ------------------------------------------------------------------------------

_FORK = multiprocessing.get_context("fork")


def _in_children(calls: list[tuple]) -> list:
    """Run each ``fn(barrier, *args)`` of ``calls`` in its own forked process, released together by
    one barrier; return ``(status, value)`` per call, in order."""
    barrier, queue = _FORK.Barrier(len(calls)), _FORK.Queue()

    def child(i: int) -> None:
        fn, *args = calls[i]
        try:
            queue.put((i, "ok", fn(barrier, *args)))
        except BaseException as e:  # report everything: the test decides what is acceptable
            queue.put((i, "error", (type(e).__name__, str(e), traceback.format_exc())))

    procs = [_FORK.Process(target=child, args=(i,)) for i in range(len(calls))]
    for p in procs:
        p.start()
    results = {i: (status, value) for i, status, value in (queue.get(timeout=240) for _ in procs)}
    for p in procs:
        p.join(30)
    return [results[i] for i in range(len(calls))]


def _load_once(barrier, ref: str) -> tuple[str, bool, tuple]:
    barrier.wait()
    loaded = load_env(ref, trust_remote_code=True)
    obs, _ = gym.make(loaded.gym_id).reset(seed=0)
    return loaded.revision, loaded.report.features.ok, tuple(obs["agent_pos"].tolist())


def test_16_processes_loading_the_same_repo_into_one_cache_all_succeed(faulty, tmp_path):
    ref = f"flt/base@{faulty.sha}"
    with hub_environment(faulty.endpoint, tmp_path / "shared-home"):
        results = _in_children([(_load_once, ref)] * 16)
        failures = [value for status, value in results if status != "ok"]
        assert failures == []
        assert {value for _, value in results} == {results[0][1]}  # same sha, checks ok, same first observation
        assert results[0][1][0] == faulty.sha and results[0][1][1]
        loaded = load_env(ref, trust_remote_code=True)  # and the cache they filled together verifies
        assert loaded.report.integrity.endswith("match the manifest")
        loaded.unregister()
        assert _incomplete(tmp_path / "shared-home") == []


def test_a_cached_snapshot_still_being_filled_is_completed_in_place_not_dropped(faulty, tmp_path):
    """A load that finds the commit's manifest in a shared cache while other processes are still downloading the rest
    (what the 16-process test above once hit) fetches the files it misses; it must not remove the snapshot folder,
    which made the other processes' downloads fail (their symlinks had no folder left)."""
    ref = f"flt/base@{faulty.sha}"
    with hub_environment(faulty.endpoint, tmp_path / "home"):
        loaded = load_env(ref, trust_remote_code=True)
        snapshot, listed = loaded.path, sorted(loaded.manifest.files)
        loaded.unregister()
        folder = os.open(snapshot, os.O_RDONLY | os.O_DIRECTORY)  # a removed folder keeps no link: st_nlink 0
        try:
            not_yet = [p for p in listed if p != "hub_env.json" and (snapshot / p).is_file()][:3]
            for p in not_yet:  # as if still downloading: only the links are missing, the blobs stay
                (snapshot / p).unlink()
            again = load_env(ref, trust_remote_code=True)
            assert again.report.integrity.endswith("match the manifest")
            assert os.fstat(folder).st_nlink > 0, "the snapshot folder was removed (and made again)"
            assert all((snapshot / p).is_file() for p in not_yet)
            again.unregister()
        finally:
            os.close(folder)


def _push_once(barrier, folder: str, seed: int) -> str:
    barrier.wait()
    return push_env(folder, "flt/race", episodes=2, seed=seed, progress=False).sha


def test_two_pushes_racing_on_one_repo_leave_a_consistent_history(faulty, tmp_path):
    with hub_environment(faulty.endpoint, tmp_path / "home"):
        first = push_env(TINY, "flt/race", episodes=2, progress=False).sha  # both racers start from this main
        folder = str(copy_env(tmp_path))
        results = _in_children([(_push_once, folder, 1), (_push_once, folder, 2)])  # different content
        winners = [value for status, value in results if status == "ok"]
        losers = [value for status, value in results if status != "ok"]
        assert winners, f"no push landed: {losers}"
        for name, message, _ in losers:  # a loser fails cleanly, with a typed error that says what to do
            assert name == "ConcurrentPushError" and "Re-run push_env" in message and "nothing was written" in message
        history = [c.commit_id for c in faulty.api.list_repo_commits("flt/race")]
        assert history[0] in winners and first in history
        assert set(winners) <= set(history) and len(history) == 2 + len(winners)  # create_repo's + first + winners
        for sha in [first, *winners]:  # every commit on main is a complete, valid env
            loaded = load_env(f"flt/race@{sha}", trust_remote_code=True)
            assert loaded.report.features.ok and "matches" in loaded.report.fingerprint
            loaded.unregister()
