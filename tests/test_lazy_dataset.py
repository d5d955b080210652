"""Lazy datasets: ``load_env`` fetches the code, the manifest, the card, media and the dataset's
``meta/`` only; the data files come (verified against the manifest) when the dataset is opened.

What was fetched is read from the Hugging Face cache itself (the files of the snapshot, the blobs),
against the real loopback server.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers import TINY

from hub_envs import errors, load_env, push_env
from hub_envs.repo_format import is_lazy_file
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
            assert (loaded.path / "dataset/meta/info.json").is_file() and (loaded.path / "media/rollout.gif").is_file()
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
