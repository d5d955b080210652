"""``hub-envs evaluate`` on this machine against a real loopback Hub: a policy over seeded episodes, the same
result whether the env runs in this process or in isolated worker processes, and typed errors for bad input.
(On Ray: tests/ray_cases.py.)"""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import TINY

from hub_envs import errors, evaluate, push_env
from hub_envs.cli import main as cli_main


@pytest.fixture(scope="module")
def tiny(hub_module):
    return f"alice/tiny@{push_env(TINY, 'alice/tiny', episodes=2, progress=False).sha}"


def push_right(obs, t):
    """A deterministic policy: full force to the right (module level, so worker processes can unpickle it)."""
    return np.ones(1, dtype=np.float32)


@pytest.mark.parametrize("policy", [None, push_right], ids=["random", "callable"])
def test_an_isolated_env_evaluates_to_the_same_result(tiny, policy):
    here = evaluate(tiny, policy=policy, episodes=3, seed=5, trust_remote_code=True, workers=1, progress=False)
    isolated = evaluate(
        tiny, policy=policy, episodes=3, seed=5, trust_remote_code=True, workers=1, progress=False, isolation="process"
    )
    assert isolated.isolation == "process" and here.isolation == "none"
    assert (isolated.returns, isolated.successes, isolated.lengths) == (here.returns, here.successes, here.lengths)
    assert here.seeds == (5, 6, 7) and here.sha == tiny.split("@")[1]
    if policy is not None:  # the policy drives the env: not the random result
        random = evaluate(tiny, episodes=3, seed=5, trust_remote_code=True, workers=1, progress=False)
        assert random.returns != here.returns


def test_the_cli_evaluates_isolated_and_records_how(tiny, tmp_path, capsys):
    code = cli_main(
        [
            "evaluate",
            f"--repo_id={tiny}",
            "--trust_remote_code=true",
            "--episodes=2",
            "--isolation=process",
            f"--out={tmp_path}",
            "--json=true",
        ]
    )
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    saved = json.loads((tmp_path / "eval.json").read_text())
    assert printed == saved and saved["isolation"] == "process" and saved["policy"] == "random"
    here = evaluate(tiny, episodes=2, trust_remote_code=True, workers=1, progress=False)  # the env in this process
    assert saved["returns"] == list(here.returns) and saved["seeds"] == [0, 1] and saved["sha"] == here.sha


def test_bad_input_is_a_typed_error(tiny):
    with pytest.raises(errors.ConfigError, match="episodes=0"):
        evaluate(tiny, episodes=0, trust_remote_code=True)
    with pytest.raises(errors.ConfigError, match="policy=42"):
        evaluate(tiny, policy=42, episodes=1, trust_remote_code=True, progress=False)
    with pytest.raises(errors.UntrustedCodeError, match="alice/tiny"):
        evaluate(tiny, episodes=1, progress=False)


def test_evaluating_an_env_the_user_has_loaded_leaves_their_load_registered(tiny):
    """evaluate (like reproduce, diff and compare) loads the env and unregisters it at the end: a load of the same
    repo@sha the user holds shares the registration, and keeps it until the user lets go."""
    import gymnasium as gym

    from hub_envs import load_env
    from hub_envs.loading.loaded import loaded_env_for_type

    mine = load_env(tiny, trust_remote_code=True)
    evaluate(tiny, episodes=1, trust_remote_code=True, workers=1, progress=False)
    assert mine.gym_id in gym.registry and loaded_env_for_type(mine.env_type) is mine
    gym.make(mine.gym_id).close()
    mine.unregister()
    mine.unregister()  # a second call does nothing
    assert mine.gym_id not in gym.registry and loaded_env_for_type(mine.env_type) is None
