"""``hub-envs untrust user/name[@<sha>]``: forget the trust entries of a repo (of one commit, with ``@<sha>``)."""

from __future__ import annotations

from dataclasses import dataclass

from hub_envs.errors import ConfigError
from hub_envs.repo import trust_list
from hub_envs.repo.refs import parse_repo_ref

USAGE = "usage: hub-envs untrust user/name[@<40-hex sha>]"


@dataclass
class Config:
    """Forget the trust entries of a repo (of one commit, with @<sha>)."""

    repo_id: str | None = None  # user/name (every trusted commit) or user/name@<sha> (that one); may come first, without the flag


def main(config: Config) -> int:
    """Remove the trust entries of ``config.repo_id`` (``user/name[@<sha>]``).

    Args:
        config: the command's flags.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    if config.repo_id is None:
        raise ConfigError(USAGE)
    repo_id, sha = parse_repo_ref(config.repo_id)
    n = trust_list.untrust(repo_id, sha)
    print(f"Removed {n} trust entr{'y' if n == 1 else 'ies'} for {repo_id}.")
    return 0
