"""``hub-envs evaluate``: a policy over N seeded episodes of an env repo, locally or on a Ray cluster."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from hub_envs.cli.flags import EnvFlags, code_run
from hub_envs.errors import ConfigError


@dataclass
class Config(EnvFlags):
    """Evaluate a policy over N seeded episodes of an env repo (locally or on a Ray cluster)."""

    policy: str = "random"  # 'random' or a LeRobot checkpoint user/policy@<sha>
    trust_policy_code: bool = False  # consent to load the policy checkpoint (another repo than the env)
    episodes: int = 10  # how many seeded episodes to run
    seed: int = 0  # episode i resets with seed + i
    max_steps: int | None = None  # default: the env config's episode_length
    backend: str = "local"  # where the episodes run: local (this machine's processes) or ray (a Ray cluster)
    workers: int = 0  # 0: up to 2 processes (local), the cluster's CPUs (ray)
    ray_address: str | None = None  # --backend=ray: the cluster; default $RAY_ADDRESS, else a local Ray for the run
    out: Path | None = None  # eval.json here; on Ray also the finished shards (a re-run skips them)
    json: bool = False  # print the result as JSON
    task: str | None = None  # a benchmark suite: the task(s) to evaluate, comma-separated (default: all, each reported)


def main(config: Config) -> int:
    """Evaluate ``config.policy`` on ``config.repo_id`` and print the result (``--json=true``: as JSON).

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.operations.evaluate import evaluate  # heavy: lerobot, torch (after the flags are parsed)

    if config.repo_id is None:
        raise ConfigError("hub-envs evaluate needs --repo_id=user/name@<sha> (or a local folder).")
    result = evaluate(
        config.repo_id,
        policy=config.policy,
        episodes=config.episodes,
        seed=config.seed,
        max_steps=config.max_steps,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        trust_policy_code=config.trust_policy_code,
        backend=config.backend,
        workers=config.workers or None,
        ray_address=config.ray_address,
        out=config.out,
        task=config.task,
        **code_run(config),
    )
    print(json.dumps(result.to_dict(), indent=2) if config.json else result.summary(), file=sys.stdout)
    return 0
