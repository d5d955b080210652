"""``hub-envs adopt --from_repo=user/name[@rev][:path] --repo_id=me/name``: publish a hub-envs repo from a plain LeRobot
EnvHub repo (its code pinned to the source commit; a dataset, the checks and a card, as push_env makes them)."""

from __future__ import annotations

from dataclasses import dataclass

from hub_envs.errors import ConfigError

#: ``hub-envs adopt user/name[@rev][:path] me/name``: the source, then the repo to publish.
POSITIONAL = ("from_repo", "repo_id")


@dataclass
class Config:
    """Adopt a plain LeRobot EnvHub repo (its code runs: consent as for load)."""

    from_repo: str | None = None  # user/name[@rev][:path], as LeRobot's make_env takes it
    repo_id: str | None = None  # the hub-envs repo to publish
    revision: str | None = None  # of from_repo
    trust_remote_code: bool = False  # consent to run from_repo's code (or trust it first: hub-envs trust)
    episodes: int = 10  # episodes of the random-action dataset
    seed: int = 0  # the first episode's reset seed (episode i: seed + i)
    private: bool = False  # create the repo private
    audit_output: str = ""  # a file for the source's audit (JSON)


def main(config: Config) -> int:
    """Adopt ``config.from_repo`` as ``config.repo_id`` and print what was published.

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    from hub_envs.publishing.adopt import adopt  # heavy: gymnasium, lerobot (after the flags are parsed)

    if config.from_repo is None or config.repo_id is None:
        raise ConfigError("hub-envs adopt needs --from_repo=user/name[@rev][:path] and --repo_id=me/name.")
    result = adopt(
        config.from_repo,
        config.repo_id,
        revision=config.revision,
        trust_remote_code=config.trust_remote_code,
        audit_output=config.audit_output or None,
        episodes=config.episodes,
        seed=config.seed,
        private=config.private,
    )
    print(f"Adopted {config.from_repo} as {config.repo_id}@{result.sha}")
    print(f'  load_env("{config.repo_id}@{result.sha}", trust_remote_code=True)')
    return 0
