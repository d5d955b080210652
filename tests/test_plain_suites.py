"""A plain LeRobot EnvHub repo whose ``make_env`` returns a benchmark suite (``{suite: {task_id: VectorEnv}}``), uploaded
with ``HfApi().upload_folder``: load_env exposes its tasks, ``hub-envs audit`` checks and reports each task, and ``hub-envs
adopt`` publishes a hub-envs suite from it (one dataset holding every task) on which LeRobot's ``make_env`` gives the same
suite and tasks as on the source, and ``hub-envs reproduce`` says REPRODUCED per task (issue #32's acceptance)."""

from __future__ import annotations

import json
import time
import warnings

import draccus
import numpy as np
import pandas as pd
import plain_repos as pr
import pytest

from hub_envs import load_env
from hub_envs.cli import main as cli
from hub_envs.envcode.registration import snapshot_registries
from hub_envs.errors import ConfigError, PlainRepoWarning, UntrustedCodeError

EPISODES = 3


def upload(hub, repo_id, folder) -> str:
    hub.api.create_repo(repo_id, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # huggingface_hub: a README without card metadata
        return hub.api.upload_folder(repo_id=repo_id, folder_path=str(folder)).oid


def rollout(vec, seed: int, steps: int = 25) -> list:
    """Observations and rewards of a seeded random-action rollout of a vector env (the actions seeded too), up to the
    first end of an episode (what comes then depends on the vector env's autoreset mode, not on the env)."""
    obs, _ = vec.reset(seed=seed)
    vec.action_space.seed(seed)
    out = [obs["agent_pos"].copy()]
    for _ in range(steps):
        obs, reward, term, trunc, _ = vec.step(vec.action_space.sample())
        out.append(np.asarray(reward).copy())
        if np.any(term) or np.any(trunc):  # the observation of this step is a reset's in SAME_STEP autoreset
            break
        out.append(obs["agent_pos"].copy())
    return out


def same_rollouts(a, b, seed: int) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(rollout(a, seed), rollout(b, seed), strict=True))


def described(envs: dict) -> dict:
    """``{suite: {task_id: (task, task_description)}}`` of a suite, as lerobot-eval reads them from each task's envs."""
    return {
        suite: {tid: (vec.call("task")[0], vec.call("task_description")[0]) for tid, vec in by_task.items()}
        for suite, by_task in envs.items()
    }


def close_all(envs: dict) -> None:
    for by_task in envs.values():
        for vec in by_task.values():
            vec.close()


def test_a_plain_suite_repo_loads_audits_adopts_and_reproduces_per_task(hub, tmp_path, capsys, monkeypatch):
    from lerobot.configs.eval import EvalPipelineConfig
    from lerobot.envs.factory import make_env

    from hub_envs.lerobot.env import make_env as hub_make_env

    sha = upload(hub, "bob/reach-suite", pr.suite_repo(tmp_path / "reach-suite"))
    source_ref = f"bob/reach-suite@{sha}"
    expected = {"reach_suite": {i: (t, d) for i, (t, d) in enumerate(zip(pr.SUITE_TASKS, pr.SUITE_INSTRUCTIONS))}}

    # 1. load_env: only with consent, then the tasks as a hub-envs suite exposes them
    before = snapshot_registries()
    with pytest.raises(UntrustedCodeError):
        load_env(source_ref)
    assert snapshot_registries() == before
    with pytest.warns(PlainRepoWarning):
        loaded = load_env(source_ref, trust_remote_code=True)
    assert loaded.is_suite and loaded.tasks == pr.SUITE_TASKS
    assert [r["instruction"] for r in loaded.manifest.tasks] == pr.SUITE_INSTRUCTIONS
    assert loaded.config.task == "reach-near"  # the first task, by default
    far = loaded.for_task("reach-far")
    env = far.make()
    assert env.get_wrapper_attr("task_description") == "reach the far target"
    env.close()
    with pytest.raises(ConfigError, match="reach-near"):
        loaded.for_task("reach-nowhere")
    ours = loaded.make_suite(n_envs=2)
    assert described(ours) == expected  # the source's suite name and task ids, each task's env
    source = make_env(source_ref, n_envs=2, trust_remote_code=True)  # LeRobot's own loader, on the source repo
    assert described(source) == expected
    for tid in range(3):
        assert same_rollouts(ours["reach_suite"][tid], source["reach_suite"][tid], seed=tid)
    close_all(ours), close_all(source)
    loaded.unregister()

    # --env.type=hub on the plain repo: every task, or those --env.task names, under the source's suite and task ids
    def parsed(*extra):
        args = ["--env.type=hub", "--env.repo_id=bob/reach-suite", f"--env.revision={sha}", "--env.trust_remote_code=true"]
        return draccus.parse(EvalPipelineConfig, args=[*args, "--policy.type=act", *extra])

    with pytest.warns(PlainRepoWarning):
        envs = hub_make_env(parsed().env, n_envs=1)
    assert described(envs) == expected
    close_all(envs)
    envs = hub_make_env(parsed("--env.task=reach-origin,reach-near").env, n_envs=1)
    assert described(envs) == {"reach_suite": {2: expected["reach_suite"][2], 0: expected["reach_suite"][0]}}
    close_all(envs)

    # 2. audit: every check per task, reported per task (text and JSON), nothing published
    assert cli(["audit", source_ref, "--trust_remote_code=true", f"--output={tmp_path / 'audit.json'}"]) == 0
    out = capsys.readouterr().out
    for i, task in enumerate(pr.SUITE_TASKS):
        assert f"task {i} '{task}'" in out
    saved = json.loads((tmp_path / "audit.json").read_text())
    assert saved["passed"] is True and [t["task"] for t in saved["tasks"]] == pr.SUITE_TASKS
    for part in saved["tasks"]:
        names = {c["name"] for c in part["checks"] if c["passed"]}
        assert {
            "final_info autoreset",
            "gymnasium check_env",
            "is_success in info",
            "seeding and whole-episode determinism",
        } <= names
    assert {m.id for m in hub.api.list_models()} == {"bob/reach-suite"}

    # 3. adopt: one hub-envs suite, one dataset holding every task
    start = time.perf_counter()
    code = cli(
        ["adopt", f"--from_repo={source_ref}", "--repo_id=me/reach-suite", "--trust_remote_code=true", f"--episodes={EPISODES}"]
    )
    seconds = time.perf_counter() - start
    assert code == 0
    adopted_sha = hub.api.model_info("me/reach-suite").sha
    files = list(hub.api.list_repo_tree("me/reach-suite", revision=adopted_sha, recursive=True))
    size = sum(getattr(f, "size", 0) or 0 for f in files)
    data = list(hub.api.list_repo_tree("me/reach-suite", repo_type="dataset", recursive=True))  # LeRobot's own tools read it
    with capsys.disabled():  # the figures of the adoption (no assertion on them: speed lives in benchmarks/)
        print(
            f"\nadopt of a {len(pr.SUITE_TASKS)}-task plain suite: {seconds:.2f} s; env repo {size} bytes in {len(files)} "
            f"entries, dataset repo {sum(getattr(f, 'size', 0) or 0 for f in data)} bytes"
        )
    adopted = load_env(f"me/reach-suite@{adopted_sha}", trust_remote_code=True)
    assert adopted.manifest.format_version == 4 and adopted.tasks == pr.SUITE_TASKS
    assert adopted.manifest.name == "reach_suite" and adopted.missing_guarantees == ()
    origin = json.loads((adopted.path / "adopted_from.json").read_text())
    assert origin["source"] == source_ref
    assert origin["tasks"] == [{"task": t, "suite": "reach_suite", "task_id": i} for i, t in enumerate(pr.SUITE_TASKS)]
    root = adopted.fetch_dataset()
    tasks = pd.read_parquet(root / "meta" / "tasks.parquet")
    assert dict(zip(tasks.index, tasks["task_index"], strict=True)) == {d: i for i, d in enumerate(pr.SUITE_INSTRUCTIONS)}
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["total_tasks"] == 3 and info["total_episodes"] == 3 * EPISODES
    adopted.unregister()

    # 4. LeRobot's make_env on the adopted repo: the same suite, task ids, tasks and instructions, the same envs
    source = make_env(source_ref, n_envs=1, trust_remote_code=True)
    theirs = make_env(f"me/reach-suite@{adopted_sha}", n_envs=1, trust_remote_code=True)
    assert described(theirs) == described(source) == expected
    for tid in range(3):
        assert same_rollouts(theirs["reach_suite"][tid], source["reach_suite"][tid], seed=10 + tid)
    close_all(theirs), close_all(source)

    # 5. hub-envs reproduce on the adopted repo: REPRODUCED per task
    capsys.readouterr()
    monkeypatch.chdir(tmp_path)
    assert cli(["reproduce", "--repo_id=me/reach-suite", f"--revision={adopted_sha}", "--trust_remote_code=true"]) == 0
    printed = capsys.readouterr().out
    assert f"REPRODUCED: me/reach-suite@{adopted_sha} (a suite of 3 tasks: 3 of 3 reproduced)" in printed
    for i, task in enumerate(pr.SUITE_TASKS):
        assert f"task {i} '{task}': REPRODUCED" in printed


def test_tasks_without_distinct_names_and_several_suites_load_but_are_not_adopted(hub, tmp_path):
    from hub_envs import adopt
    from hub_envs.errors import EnvContractError

    sha = upload(hub, "bob/two", pr.two_suites_repo(tmp_path / "two"))
    with pytest.warns(PlainRepoWarning):
        loaded = load_env(f"bob/two@{sha}", trust_remote_code=True)
    assert loaded.tasks == ["near/0", "far/0"]  # every env says "reach the target": named by suite and task id
    assert [r["instruction"] for r in loaded.manifest.tasks] == ["reach the target"] * 2
    envs = loaded.make_suite()
    assert {s: list(by_task) for s, by_task in envs.items()} == {"near": [0], "far": [0]}
    close_all(envs)
    far = loaded.for_task("far/0").make()
    far.reset(seed=0)
    assert far.get_wrapper_attr("target").tolist() == [1.5, 1.5]
    far.close()
    loaded.unregister()
    with pytest.raises(
        EnvContractError, match=r"cannot be adopted as it is:\n  one suite: make_env returns 2 suites \(near, far\)"
    ):
        adopt(f"bob/two@{sha}", "me/two", trust_remote_code=True, episodes=2, progress=False)
    assert "me/two" not in {m.id for m in hub.api.list_models()}
    before = snapshot_registries()
    with pytest.raises(
        EnvContractError, match=r"empty.py breaks LeRobot's EnvHub contract: make_env returned a suite with no task"
    ):
        load_env(f"bob/two@{sha}:empty.py", trust_remote_code=True)
    assert snapshot_registries() == before


def test_an_isolated_load_of_a_plain_suite_finds_its_tasks_in_a_worker(hub, tmp_path):
    sha = upload(hub, "bob/reach-suite", pr.suite_repo(tmp_path / "reach-suite"))
    with pytest.warns(PlainRepoWarning):
        isolated = load_env(f"bob/reach-suite@{sha}", trust_remote_code=True, isolation="process")
        here = load_env(f"bob/reach-suite@{sha}", trust_remote_code=True, check=False)
    assert isolated.runs_as == "process" and isolated.tasks == here.tasks == pr.SUITE_TASKS
    assert isolated.manifest.tasks == here.manifest.tasks
    action = np.array([0.3, -0.2], dtype=np.float32)
    for task in ("reach-far", "reach-origin"):  # each task's env in the worker is the one made here
        a, b = isolated.for_task(task).make(), here.for_task(task).make()
        assert np.array_equal(a.reset(seed=3)[0]["agent_pos"], b.reset(seed=3)[0]["agent_pos"])
        assert a.step(action)[1] == b.step(action)[1]
        a.close(), b.close()
    isolated.unregister()
    here.unregister()
