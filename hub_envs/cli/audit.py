"""``hub-envs audit --repo_id=user/name[@rev][:path]``: check a plain LeRobot EnvHub repo against LeRobot's conventions,
publishing nothing; a report, a JSON file, exit code 0 (every check passed) or 1."""

from __future__ import annotations

from dataclasses import dataclass

from hub_envs.errors import ConfigError


@dataclass
class Config:
    """Audit a plain LeRobot EnvHub repo (its code runs: consent as for load)."""

    repo_id: str | None = None  # user/name[@rev][:path], as LeRobot's make_env takes it
    revision: str | None = None  # the commit, branch or tag (default: the one in repo_id, else main)
    trust_remote_code: bool = False  # consent to run the repo's code (or trust it first: hub-envs trust)
    steps: int = 0  # steps per rollout (0: the env's own time limit, at most 1000)
    output: str = "audit.json"  # where the JSON report goes ("" for none)


def main(config: Config) -> int:
    """Audit ``config.repo_id``, print the report and write it as JSON.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0 every check passed, 1 one failed.

    Raises:
        HubEnvsError: what failed before any check ran (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.loading.audit import audit  # heavy: gymnasium, lerobot (after the flags are parsed)

    if config.repo_id is None:
        raise ConfigError("hub-envs audit needs --repo_id=user/name[@revision][:path/to/entry.py].")
    report = audit(
        config.repo_id,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        steps=config.steps,
        output=config.output or None,
    )
    print(report.render())
    if config.output:
        print(f"Report: {config.output}")
    return 0 if report.passed else 1
