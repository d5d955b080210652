"""Lazy datasets and media: ``load_env`` fetches the code, the manifest, the card and the dataset's
``meta/`` only; the data files come (verified against the manifest) when the dataset is opened, the
card's media when :meth:`LoadedEnv.media_file` asks. The card and ``meta/`` download while the code is
imported and checked, and are verified before load_env returns.

What was fetched is read from the Hugging Face cache itself (the files of the snapshot, the blobs),
against the real loopback server.
"""

from __future__ import annotations

import hashlib
import threading
from pathlib import Path

import gymnasium as gym
import pytest
import requests
from helpers import TINY, republish

from hub_envs import errors, load_env, push_env
from hub_envs.repo import hub_io
from hub_envs.repo.format import is_lazy_file
from hub_envs.testing import hub_environment


@pytest.fixture(scope="module")
def pushed(hub_module, tmp_path_factory):
    with hub_environment(hub_module.endpoint, tmp_path_factory.mktemp("pusher")):
        result = push_env(TINY, "lazy/tiny", episodes=3, progress=False)
    return hub_module, result.sha


def _data_files(manifest_files) -> list[str]:
    return sorted(p for p in manifest_files if is_lazy_file(p))


def test_a_cold_load_fetches_no_data_file_and_opening_the_dataset_fetches_and_verifies_them(pushed, tmp_path):
    hub, sha = pushed
    with hub_environment(hub.endpoint, tmp_path / "home"):
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        try:
            data = _data_files(loaded.manifest.files)
            assert data and all(p.startswith("dataset/data/") for p in data)
            assert not any((loaded.path / p).exists() for p in data)  # not in the snapshot...
            blobs = loaded.path.parent.parent / "blobs"
            # ...nor as blobs (an LFS file's blob is named by its sha256, the manifest's hash)
            assert blobs.is_dir() and not any((blobs / loaded.manifest.files[p]).exists() for p in data)
            # everything else is there and verified; the three-way check read meta/info.json
            assert (loaded.path / "dataset/meta/info.json").is_file() and (loaded.path / "README.md").is_file()
            assert loaded.report.features.ok and "dataset" in loaded.report.features.table()

            dataset = loaded.open_dataset()  # fetches the data files, checks each sha256
            assert dataset.num_episodes == 3 and dataset.num_frames == loaded.manifest.dataset["frames"]
            assert all((loaded.path / p).is_file() and (blobs / loaded.manifest.files[p]).is_file() for p in data)
            assert loaded.dataset_root == loaded.path / "dataset"
        finally:
            loaded.unregister()


def test_offline_with_only_the_code_cached_loads_and_opening_the_dataset_says_what_to_fetch(pushed, tmp_path):
    hub, sha = pushed
    home = tmp_path / "home"
    with hub_environment(hub.endpoint, home):
        load_env(f"lazy/tiny@{sha}", trust_remote_code=True).unregister()
    with hub_environment(hub.endpoint, home, offline=True):
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)  # the code is cached: loads, checks
        try:
            assert loaded.report.features.ok
            with pytest.raises(errors.DatasetNotCachedError) as e:
                loaded.open_dataset()
            message = str(e.value)
            assert f"lazy/tiny@{sha}" in message and "dataset/data/" in message
            assert "HF_HUB_OFFLINE" in message and "fetch_dataset()" in message
            assert isinstance(e.value, errors.OfflineNotCachedError) and isinstance(e.value, errors.DatasetError)
        finally:
            loaded.unregister()
    with hub_environment(hub.endpoint, home):  # online again: the same cache completes
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        assert loaded.open_dataset().num_episodes == 3
        loaded.unregister()


def test_a_data_file_that_differs_from_the_manifest_is_refused_when_fetched_and_fetched_again(pushed, tmp_path):
    hub, sha = pushed
    with hub_environment(hub.endpoint, tmp_path / "home"):
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        try:
            loaded.fetch_dataset()
            victim = loaded.path / _data_files(loaded.manifest.files)[0]
            blob = Path(victim.resolve())
            blob.chmod(0o644)
            blob.write_bytes(blob.read_bytes()[:-10] + b"0123456789")  # the cache was damaged, or the bytes rewritten
            again = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)  # the load itself does not read data files
            with pytest.raises(errors.IntegrityError, match="differ from the manifest") as e:
                again.open_dataset()
            assert victim.name in str(e.value) and not victim.exists()  # removed from the cache
            assert again.open_dataset().num_episodes == 3  # and fetched again, verified
        finally:
            loaded.unregister()


# --- the card's media: fetched on demand; the card and meta/: beside the checks --------------------


def _fetching_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("hub-envs-fetch")]


def test_a_cold_load_fetches_no_media_file_and_media_file_fetches_and_verifies_it(pushed, tmp_path):
    hub, sha = pushed
    home = tmp_path / "home"
    with hub_environment(hub.endpoint, home):
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        try:
            media = sorted(p for p in loaded.manifest.files if p.startswith("media/"))
            assert media == ["media/rollout.gif"]
            blobs = loaded.path.parent.parent / "blobs"
            assert not (loaded.path / "media").exists()  # neither in the snapshot nor as a blob
            assert not (blobs / loaded.manifest.files["media/rollout.gif"]).exists()
            # everything the load fetched is there, and verified (the card and meta/ arrived during the checks)
            meta = [p for p in loaded.manifest.files if p.startswith("dataset/meta/")]
            assert all((loaded.path / p).is_file() for p in [*meta, "README.md"]) and not _fetching_threads()

            gif = loaded.media_file()  # fetched now, checked against the manifest
            assert gif == loaded.path / "media/rollout.gif" and gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
            assert hashlib.sha256(gif.read_bytes()).hexdigest() == loaded.manifest.files["media/rollout.gif"]
            with pytest.raises(errors.InvalidRepoFormatError, match="media/rollout.gif"):
                loaded.media_file("rollout.mp4")  # no video in this repo: the message lists its media

            blob = Path(gif.resolve())  # the cache damaged: refused, removed, fetched again
            blob.chmod(0o644)
            blob.write_bytes(b"GIF89a" + b"\0" * 20)
            with pytest.raises(errors.IntegrityError, match="media/rollout.gif") as e:
                loaded.media_file()
            assert "removed from the cache" in str(e.value) and not gif.exists()
            assert hashlib.sha256(loaded.media_file().read_bytes()).hexdigest() == loaded.manifest.files["media/rollout.gif"]
        finally:
            loaded.unregister()

    # the card and the web page still show it: the server serves the media, pinned to the commit
    page = requests.get(f"{hub.endpoint}/lazy/tiny", headers={"Accept": "text/html"}, timeout=30).text
    assert f'src="/lazy/tiny/resolve/{sha}/media/rollout.gif"' in page
    served = requests.get(f"{hub.endpoint}/lazy/tiny/resolve/{sha}/media/rollout.gif", timeout=30).content
    assert hashlib.sha256(served).hexdigest() == loaded.manifest.files["media/rollout.gif"]
    assert "](media/rollout.gif)" in (loaded.path / "README.md").read_text()

    other = tmp_path / "other"  # offline, with only the code cached: loads; the media says how to fetch it
    with hub_environment(hub.endpoint, other):
        load_env(f"lazy/tiny@{sha}", trust_remote_code=True).unregister()
    with hub_environment(hub.endpoint, other, offline=True):
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        try:
            with pytest.raises(errors.OfflineNotCachedError, match="HF_HUB_OFFLINE") as e:
                loaded.media_file()
            assert f"lazy/tiny@{sha}" in str(e.value) and "media/rollout.gif" in str(e.value)
        finally:
            loaded.unregister()


@pytest.mark.parametrize("victim", ["README.md", "dataset/meta/stats.json"])
def test_a_card_or_meta_file_that_differs_from_the_manifest_is_refused_and_nothing_stays_registered(pushed, tmp_path, victim):
    """The card and meta/ download while the code is imported and checked: a file that differs from the manifest
    still stops the load (after the checks, before load_env returns), undoes the registration and leaves no
    snapshot behind."""
    hub, _ = pushed
    repo = f"lazy/bad-{victim.split('/')[-1].replace('.', '-').lower()}"
    hub.api.create_repo(repo)
    with hub_environment(hub.endpoint, tmp_path / "pusher"):
        good = push_env(TINY, repo, episodes=2, progress=False).sha

    def damage(folder: Path) -> None:
        path = folder / victim
        path.write_bytes(path.read_bytes() + b"\n ")  # the manifest still lists the published sha256

    sha = republish(hub.api, repo, damage, fix_hashes=False, message="damaged")
    assert sha != good
    with hub_environment(hub.endpoint, tmp_path / "home"):
        before = set(gym.registry)
        with pytest.raises(errors.IntegrityError, match="do not match the manifest") as e:
            load_env(f"{repo}@{sha}", trust_remote_code=True)
        assert f"tampered  {victim}" in str(e.value)
        assert set(gym.registry) == before  # the registration was undone
        assert not hub_io.snapshot_cache_dir(repo, sha).exists()  # the snapshot was removed
        assert not _fetching_threads()
        loaded = load_env(f"{repo}@{good}", trust_remote_code=True)  # the good commit loads in the same cache
        loaded.unregister()


def test_a_refused_load_leaves_no_download_running(pushed, tmp_path):
    hub, sha = pushed
    with hub_environment(hub.endpoint, tmp_path / "home"):
        with pytest.raises(errors.UntrustedCodeError):
            load_env(f"lazy/tiny@{sha}")  # no consent: refused after the code arrived, while the card may still come
        assert not _fetching_threads()
        # what arrived is a consistent part of the snapshot: a load with consent completes and verifies it
        loaded = load_env(f"lazy/tiny@{sha}", trust_remote_code=True)
        assert (loaded.path / "README.md").is_file() and loaded.report.features.ok
        loaded.unregister()
