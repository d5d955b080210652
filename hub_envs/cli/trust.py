"""``hub-envs trust user/name@<sha>``: trust one commit of a repo, with exactly its content (remembered)."""

from __future__ import annotations

from dataclasses import dataclass

from hub_envs.errors import ConfigError
from hub_envs.repo import trust_list
from hub_envs.repo.format import is_commit_sha
from hub_envs.repo.refs import parse_repo_ref

USAGE = "usage: hub-envs trust user/name@<40-hex sha>"


@dataclass
class Config:
    """Trust one commit of a repo, with exactly its content: load_env then runs its code without asking."""

    repo_id: str | None = None  # the commit to trust, user/name@<40-hex sha>; may come first, without the flag


def main(config: Config) -> int:
    """Trust ``config.repo_id`` (``user/name@<sha>``): load_env then runs that commit's code, with exactly its content, without asking.

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
    if sha is None or not is_commit_sha(sha):
        raise ConfigError(
            f"Trust is given to an exact commit: hub-envs trust {repo_id}@<40-hex sha> (load_env and the card print the sha)."
        )
    digest = trust_list.commit_digest(repo_id, sha)
    trust_list.trust(repo_id, sha, content_digest=digest)
    print(
        f"Trusted {repo_id}@{sha} (content {digest[:16]}…): hub-envs will run its code at this commit, "
        f"with exactly this content, without asking."
    )
    return 0
