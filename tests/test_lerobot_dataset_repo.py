"""LeRobot's own dataset tools open an env's dataset by repo id: ``LeRobotDataset(repo_id)`` and
``lerobot-dataset-viz --repo-id`` (``lerobot-train --dataset.repo_id`` runs in tests/journeys).

push_env also publishes the dataset as the dataset-type repo of the same name: the same files, byte for byte,
committed before the env commit, named by the env's manifest, and opened by LeRobot through its ``v3.0`` tag,
which moves only once the env commit is made. Real parts: the loopback Hub server, huggingface_hub, LeRobot's
``LeRobotDataset`` and its visualizer script in a fresh process, on both stacks.
"""

from __future__ import annotations

import hashlib
import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import TINY, copy_env
from huggingface_hub import HfApi

from hub_envs import errors, load_env, push_env
from hub_envs.dataset.env_meta import read_env_meta
from hub_envs.dataset.reader import read_episode_frames, read_hub_envs_meta, read_info
from hub_envs.dataset.writer import EpisodeFrames, write_lerobot_dataset
from hub_envs.publishing.dataset_repo import LEROBOT_DATASET_TAG
from hub_envs.testing import HubServer, hub_environment

DATASET = "dataset"


def _lerobot_dataset(repo_id: str, **kwargs):
    """What a LeRobot user writes: the repo id, nothing else (``kwargs``: a ``revision``)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(repo_id, **kwargs)


def _tags(api: HfApi, repo_id: str) -> dict[str, str]:
    return {t.name: t.target_commit for t in api.list_repo_refs(repo_id, repo_type=DATASET).tags}


def _dataset_files_of(manifest) -> dict[str, str]:
    """The env repo's ``dataset/`` files and their sha256, as its manifest lists them (paths inside the dataset)."""
    return {p.removeprefix("dataset/"): h for p, h in manifest.files.items() if p.startswith("dataset/")}


def _files_in(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for top in ("data", "meta", "videos")
        if (root / top).is_dir()
        for p in (root / top).rglob("*")
        if p.is_file()
    }


def test_lerobot_opens_the_env_dataset_by_repo_id_at_the_published_revision(hub, tmp_path):
    v1 = push_env(TINY, "alice/tiny-ds", episodes=2, progress=False)
    record = v1.manifest.dataset["dataset_repo"]
    assert record == {"repo_id": "alice/tiny-ds", "revision": v1.dataset_sha}
    assert _tags(hub.api, "alice/tiny-ds") == {LEROBOT_DATASET_TAG: v1.dataset_sha, v1.content_tag: v1.dataset_sha}

    with hub_environment(hub.endpoint, tmp_path / "lerobot-user"):  # nothing cached: LeRobot downloads it
        ds = _lerobot_dataset("alice/tiny-ds")
        assert ds.num_episodes == 2
        # the same bytes a load_env user gets: every file is the one the env's manifest hashes
        assert _files_in(Path(ds.root)) == _dataset_files_of(v1.manifest)
        loaded = load_env(f"alice/tiny-ds@{v1.sha}", trust_remote_code=True)
        try:
            frames = read_episode_frames(loaded.fetch_dataset(), 1)
        finally:
            loaded.unregister()
        first = int(ds.meta.episodes["dataset_from_index"][1])
        np.testing.assert_array_equal(ds[first + 3]["observation.state"].numpy(), frames["observation.state"][3])

    v2 = push_env(TINY, "alice/tiny-ds", episodes=3, progress=False)
    assert v2.created_commit and v2.dataset_sha != v1.dataset_sha
    assert _tags(hub.api, "alice/tiny-ds")[LEROBOT_DATASET_TAG] == v2.dataset_sha
    with hub_environment(hub.endpoint, tmp_path / "lerobot-user-2"):
        assert _lerobot_dataset("alice/tiny-ds").num_episodes == 3  # the latest publication
    # (a fresh cache: LeRobot 0.4.4 keeps one local copy per repo id, whatever its revision)
    with hub_environment(hub.endpoint, tmp_path / "lerobot-user-3"):
        old = _lerobot_dataset("alice/tiny-ds", revision=v1.content_tag)  # pinned by the card's content tag
        assert old.num_episodes == 2 and _files_in(Path(old.root)) == _dataset_files_of(v1.manifest)

    # an unchanged re-push commits nothing, to either repo, and moves no tag
    commits = len(hub.api.list_repo_commits("alice/tiny-ds", repo_type=DATASET))
    again = push_env(TINY, "alice/tiny-ds", episodes=3, progress=False)
    assert not again.created_commit and again.sha == v2.sha and again.dataset_sha == v2.dataset_sha
    assert len(hub.api.list_repo_commits("alice/tiny-ds", repo_type=DATASET)) == commits
    assert 'LeRobotDataset("alice/tiny-ds")' in again.summary()
    card = Path(hub.api.hf_hub_download("alice/tiny-ds", "README.md", repo_type=DATASET)).read_text()
    assert "LeRobot" in card and f'revision="{v2.content_tag}"' in card and "[alice/tiny-ds](/alice/tiny-ds)" in card
    env_card = Path(hub.api.hf_hub_download("alice/tiny-ds", "README.md", revision=v2.sha)).read_text()
    assert 'LeRobotDataset("alice/tiny-ds")' in env_card and "datasets:\n- alice/tiny-ds" in env_card


def test_a_push_whose_env_commit_fails_leaves_lerobot_on_the_published_dataset(tmp_path):
    rules = tmp_path / "faults.json"
    rules.write_text("[]")
    server = HubServer(tmp_path / "hub-data", env={"HUB_ENVS_SERVER_FAULTS": str(rules)})
    try:
        with hub_environment(server.endpoint, tmp_path / "hf"):
            api = HfApi(endpoint=server.endpoint)
            v1 = push_env(TINY, "alice/tiny-fail", episodes=1, progress=False)
            # the env commit of the next push fails (the dataset repo's goes through)
            rules.write_text(json.dumps([{"match": "POST /api/models/alice/tiny-fail/commit/", "status": 500, "times": -1}]))
            with pytest.raises(errors.HubError, match="Push again to finish") as info:
                push_env(TINY, "alice/tiny-fail", episodes=2, progress=False)
            assert f"{LEROBOT_DATASET_TAG} tag" in str(info.value)
            ds_main = api.repo_info("alice/tiny-fail", repo_type=DATASET).sha
            assert ds_main != v1.dataset_sha  # the dataset repo's commit was made...
            assert _tags(api, "alice/tiny-fail")[LEROBOT_DATASET_TAG] == v1.dataset_sha  # ...but LeRobot is not sent there
            assert api.model_info("alice/tiny-fail").sha == v1.sha
            with hub_environment(server.endpoint, tmp_path / "lerobot-user"):
                assert _lerobot_dataset("alice/tiny-fail").num_episodes == 1  # what the env repo publishes

            rules.write_text("[]")
            v2 = push_env(TINY, "alice/tiny-fail", episodes=2, progress=False)  # pushing again finishes it
            assert v2.dataset_sha == ds_main  # the dataset was not committed a second time
            assert _tags(api, "alice/tiny-fail")[LEROBOT_DATASET_TAG] == ds_main
            assert api.model_info("alice/tiny-fail").sha == v2.sha != v1.sha
            with hub_environment(server.endpoint, tmp_path / "lerobot-user-2"):
                assert _lerobot_dataset("alice/tiny-fail").num_episodes == 2
    finally:
        server.kill()
        server.remove_log()


def test_the_dataset_repo_is_as_private_as_the_env_and_never_replaces_anothers(hub_with_token, tmp_path):
    hub = hub_with_token
    pushed = push_env(TINY, "alice/secret", episodes=1, private=True, progress=False)
    assert hub.api.repo_info("alice/secret", repo_type=DATASET).private
    anonymous = HfApi(endpoint=hub.endpoint, token=False)
    with pytest.raises(Exception, match="401|404|Repository Not Found"):
        anonymous.list_repo_refs("alice/secret", repo_type=DATASET)
    with hub_environment(hub.endpoint, tmp_path / "lerobot-user", token=hub.token):  # the owner's token opens it
        assert _lerobot_dataset("alice/secret").num_episodes == 1
    assert pushed.dataset_sha == _tags(hub.api, "alice/secret")[LEROBOT_DATASET_TAG]

    # an env made private later, beside its public dataset repo: a changed push refuses before writing anything
    push_env(TINY, "alice/went-private", episodes=1, progress=False)
    hub.api.update_repo_settings("alice/went-private", private=True)
    heads = (hub.api.model_info("alice/went-private").sha, hub.api.repo_info("alice/went-private", repo_type=DATASET).sha)
    with pytest.raises(errors.ConfigError, match="would make the private env's dataset public. Nothing was published"):
        push_env(TINY, "alice/went-private", episodes=2, progress=False)
    assert heads == (hub.api.model_info("alice/went-private").sha, hub.api.repo_info("alice/went-private", repo_type=DATASET).sha)

    # a dataset repo someone filled by hand is not replaced (and the env repo is not created)
    hub.api.create_repo("alice/handmade", repo_type=DATASET)
    hub.api.upload_file(path_or_fileobj=b"my data\n", path_in_repo="notes.txt", repo_id="alice/handmade", repo_type=DATASET)
    with pytest.raises(errors.ConfigError, match="holds a dataset push_env did not publish"):
        push_env(TINY, "alice/handmade", episodes=1, progress=False)
    assert hub.api.list_repo_files("alice/handmade", repo_type=DATASET) == [".gitattributes", "notes.txt"]
    assert not hub.api.repo_exists("alice/handmade")
    # ... unless asked not to publish one
    alone = push_env(TINY, "alice/handmade", episodes=1, progress=False, dataset_repo=False)
    assert alone.dataset_sha is None and "dataset_repo" not in alone.manifest.dataset


def test_lerobot_reads_only_its_own_info_keys_and_old_datasets_stay_readable(tmp_path, caplog):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {"observation.state": {"dtype": "float32", "shape": [2], "names": ["x", "v"]}}
    features["action"] = {"dtype": "float32", "shape": [2], "names": ["a", "b"]}
    episodes = [
        EpisodeFrames(i, seed=10 + i, frames={k: np.full((4, 2), i, np.float32) for k in ("observation.state", "action")})
        for i in range(2)
    ]
    root = tmp_path / "ds"
    write_lerobot_dataset(
        root, repo_id="me/ds", fps=10, features=features, episodes=episodes, task="t", progress=False, extra_info={"env": 1}
    )
    assert "hub_envs" not in read_info(root)  # hub-envs' own metadata is a file of its own, which LeRobot never reads
    assert read_hub_envs_meta(root)["seeds"] == [10, 11] and read_hub_envs_meta(root)["env"] == 1
    with caplog.at_level(logging.WARNING):
        LeRobotDataset("me/ds", root=root)
    assert not [r for r in caplog.records if "Unknown fields" in r.getMessage()]  # LeRobot >= 0.5 logged it on every open

    # a dataset written before keeps the same metadata in info.json["hub_envs"]: still read
    legacy = tmp_path / "legacy"
    write_lerobot_dataset(
        legacy,
        repo_id="me/ds",
        fps=10,
        features=features,
        episodes=episodes,
        task="t",
        progress=False,
        extra_info={"env_meta": {"env_repo_id": "alice/x", "code_digest": "0" * 64}},
    )
    meta_file = legacy / "meta" / "hub_envs.json"
    info = json.loads((legacy / "meta" / "info.json").read_text())
    info["hub_envs"] = json.loads(meta_file.read_text())
    (legacy / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    meta_file.unlink()
    assert read_hub_envs_meta(legacy)["seeds"] == [10, 11]
    assert read_env_meta(legacy)["env_repo_id"] == "alice/x"


def _tiny_2d_action(tmp_path: Path) -> Path:
    """The tiny env with a 2-D action (the second component unused) and 8-step episodes. LeRobot stores a shape-(1,)
    feature as a scalar column, and LeRobot 0.4.4's visualizer then fails on the 0-d action tensor ("iteration over a
    0-d tensor"), for LeRobot's own datasets as for these."""
    return copy_env(
        tmp_path,
        TINY,
        "tiny_2d",
        {
            "tiny.py": lambda s: (
                s.replace("spaces.Box(-1.0, 1.0, (1,), np.float32)", "spaces.Box(-1.0, 1.0, (2,), np.float32)")
                .replace("np.asarray(action, dtype=np.float64))", "np.asarray(action, dtype=np.float64)[:1])")
                .replace(
                    "PolicyFeature(type=FeatureType.ACTION, shape=(1,))", "PolicyFeature(type=FeatureType.ACTION, shape=(2,))"
                )
                .replace("episode_length: int = 30", "episode_length: int = 8")
            )
        },
    )


def test_lerobots_dataset_visualizer_opens_an_env_dataset_by_repo_id(hub, tmp_path):
    """``lerobot-dataset-viz`` (LeRobot 0.4.4 and 0.6.x alike; rerun-sdk, in LeRobot's ``viz`` extra from 0.5) takes
    only ``--repo-id`` and ``--episode-index``: it opens ``LeRobotDataset(repo_id)`` itself."""
    push_env(_tiny_2d_action(tmp_path), "alice/tiny-viz", episodes=2, progress=False)
    out = tmp_path / "rrd"
    with hub_environment(hub.endpoint, tmp_path / "viewer"):  # a fresh process, a fresh cache
        run = subprocess.run(
            [
                str(Path(sys.executable).with_name("lerobot-dataset-viz")),
                "--repo-id=alice/tiny-viz",
                "--episode-index=1",
                "--save=1",
                f"--output-dir={out}",
                "--num-workers=0",
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-4000:]
    rrd = out / "alice_tiny-viz_episode_1.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 0
