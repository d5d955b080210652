"""Journey: an author revises an env, and a user sees what changed and what it does to a policy.

push v1 -> push v2 (the same folder with an action cost in the reward: a real change of the env's reward) ->
``hub-envs diff`` between the two commits says what changed, with evidence (the file, the first divergent step
and feature, both values) -> ``hub-envs compare --against`` runs the same policy on both revisions on the same
seeds and gives the seed-paired difference with its interval. Every step is the real command line in its own
process, against the real loopback Hub (the ``hub`` fixture), as a user types it.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from helpers import copy_env

ACTION_COST = 0.1


def _hub_envs(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``hub-envs <args>`` in a process of its own, with this test's Hub settings (HF_ENDPOINT, HF_HOME, ...)."""
    env = {**os.environ, "HF_HUB_DISABLE_PROGRESS_BARS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "hub_envs.cli", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=600
    )


def _push(folder: Path, cwd: Path) -> str:
    done = _hub_envs("push", f"--env_dir={folder}", "--repo_id=alice/tiny", "--episodes=2", "--workers=1", cwd=cwd)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (sha,) = re.findall(r"Published alice/tiny at commit ([0-9a-f]{40})", done.stdout)
    return sha


def test_push_v1_push_v2_diff_then_compare_the_two_on_the_same_seeds(hub, tmp_path):
    folder = copy_env(tmp_path, name="tiny")
    v1 = _push(folder, tmp_path)

    # the author makes moving cost something, and publishes again from the same folder
    code = folder / "tiny.py"
    text = code.read_text()
    old = "        reward = -float(abs(self.pos[0]))\n"
    assert old in text
    code.write_text(
        text.replace(old, f"        reward = -float(abs(self.pos[0])) - {ACTION_COST} * float(np.abs(action).sum())\n")
    )
    v2 = _push(folder, tmp_path)
    assert v2 != v1

    # diff: what changed, and where the behaviour first diverges
    diff = _hub_envs(
        "diff", f"--old=alice/tiny@{v1}", f"--new=alice/tiny@{v2}", "--trust_remote_code=true", "--out=diff", cwd=tmp_path
    )
    assert diff.returncode == 1, diff.stdout[-3000:] + diff.stderr[-3000:]  # 1: the behaviour differs
    said = diff.stdout
    assert "BEHAVIOUR DIFFERS" in said and "code: ~1 changed (tiny.py)" in said
    assert "seed 0 (recorded actions of episode 0): next.reward diverged at step 0" in said
    report = json.loads((tmp_path / "diff" / "report.json").read_text())
    first = report["first_divergence"]
    assert (first["feature"], first["step"]) == ("next.reward", 0)
    # the evidence is the change itself: the new reward is the old one minus the action's cost
    dataset_action = _recorded_action(v1, episode=first["seed"], frame=0)
    assert first["new"] == _approx(first["old"] - ACTION_COST * abs(dataset_action))
    assert not [s for s in report["spaces"]]  # spaces unchanged: the episodes ran on both
    # every compared episode, recorded or random actions, diverges at its first reward and nowhere earlier
    assert [(s["diverged"], s["feature"], s["step"]) for s in report["seeds"]] == [(True, "next.reward", 0)] * 4

    # compare: the same policy (seeded random actions) on both revisions, on the same seeds, paired
    compare = _hub_envs(
        "compare",
        f"--repo_id=alice/tiny@{v1}",
        f"--against=alice/tiny@{v2}",
        "--policies=random",
        "--episodes=10",
        "--trust_remote_code=true",
        "--workers=1",
        "--out=compare",
        cwd=tmp_path,
    )
    assert compare.returncode == 0, compare.stdout[-3000:] + compare.stderr[-3000:]
    assert f"Compared on alice/tiny@{v1} and alice/tiny@{v2}: 10 episodes" in compare.stdout
    result = json.loads((tmp_path / "compare" / "report.json").read_text())
    old, new = result["policies"]
    assert (old["label"], new["label"]) == (f"random on @{v1[:12]}", f"random on @{v2[:12]}")
    (paired,) = result["differences"]
    assert (paired["a"], paired["b"]) == (new["label"], old["label"])  # new minus old, seed by seed
    deltas = [n - o for n, o in zip(new["returns"]["values"], old["returns"]["values"], strict=True)]
    assert paired["returns"]["values"] == _approx(deltas)
    # the same actions on the same seeds (the dynamics did not change): every episode pays its action cost, so
    # every paired difference is negative, and so is the whole interval; success did not move at all
    assert max(deltas) < 0 and paired["returns"]["ci"][1] < 0
    assert paired["successes"]["values"] == [0.0] * 10
    assert result["provenance"]["against"]["sha"] == v2 and result["seeds"] == list(range(10))


def _recorded_action(sha: str, *, episode: int, frame: int) -> float:
    from hub_envs import load_env
    from hub_envs.dataset.reader import read_episode_frames

    with load_env(f"alice/tiny@{sha}", trust_remote_code=True, check=False) as loaded:
        return float(read_episode_frames(loaded.dataset_root, episode)["action"][frame][0])


def _approx(value):
    import pytest

    return pytest.approx(value, abs=1e-6)
