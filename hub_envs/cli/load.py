"""``hub-envs load``: load an env repo, run its checks, and print what was loaded (the three-way table)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from hub_envs._text import safe_text
from hub_envs.cli.flags import EnvFlags
from hub_envs.errors import ConfigError


@dataclass
class Config(EnvFlags):
    """Load an env repo, run its checks, and print what was loaded (the three-way table)."""

    check: bool = True  # run the three-way feature check and the fingerprint check after registering the env
    fingerprint: str = "error"  # what a drifted golden-rollout fingerprint does: error, warn or off
    recheck: bool = False  # run the checks even if they passed before with the same packages (a cached verdict)
    json: bool = False  # print what was loaded as JSON


def main(config: Config) -> int:
    """Load ``config.repo_id`` and print what was loaded (``--json=true``: as JSON).

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.loading.load import load_env  # heavy: gymnasium, lerobot (after the flags are parsed)

    if config.repo_id is None:
        raise ConfigError("hub-envs load needs --repo_id=user/name[@revision] (or a local folder).")
    loaded = load_env(
        config.repo_id,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        check=config.check,
        fingerprint=config.fingerprint,
        recheck=config.recheck,
        isolation=config.isolation,
        sandbox=config.sandbox,
        versions=config.versions,
        step_timeout=config.step_timeout,
    )
    if config.json:
        print(
            json.dumps(
                {
                    "repo_id": loaded.repo_id,
                    "revision": loaded.revision,
                    "gym_id": loaded.gym_id,
                    "env_type": loaded.env_type,
                    "path": str(loaded.path),
                    "isolation": _isolation_text(loaded),
                    "tasks": loaded.tasks,
                    "report": loaded.report.to_dict(),
                },
                indent=2,
            )
        )
        return 0
    print(f"Loaded {loaded.repo_id} at {loaded.revision}")
    print(f"  gym id:      {loaded.gym_id}")
    print(f"  --env.type:  {loaded.env_type}")
    if loaded.is_suite:  # a benchmark suite: --env.task=a,b picks tasks (default all), loaded.for_task(name) makes one
        print(f"  tasks:       {safe_text(', '.join(loaded.tasks))} (default {safe_text(str(loaded.config.task))})")
    print(f"  snapshot:    {loaded.path}")
    print(f"  runs:        {_isolation_text(loaded)}")
    print(f"  integrity:   {loaded.report.integrity}")
    print(f"  trust:       {loaded.report.trust}")
    print(f"  fingerprint: {loaded.report.fingerprint}")
    for missing in loaded.missing_guarantees:  # a plain LeRobot EnvHub repo
        print(f"  cannot give: {missing}")
    if loaded.report.features is not None:
        print("  three-way feature check (declared / live / dataset):")
        print("    " + "\n    ".join(safe_text(line) for line in loaded.report.features.table().splitlines()))  # repo's names
    return 0


def _isolation_text(loaded: Any) -> str:
    iso = loaded.isolation
    if iso is None:
        return "in this process"
    return "in a sandboxed worker process" if iso.sandbox else "in a worker process"
