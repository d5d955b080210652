"""``hub-envs untrust user/name[@<sha>]``: forget the trust entries of a repo (of one commit, with ``@<sha>``)."""

from __future__ import annotations

from hub_envs.errors import ConfigError
from hub_envs.repo import trust_list
from hub_envs.repo.refs import parse_repo_ref

ARGV = True  # main(argv): one positional argument

USAGE = "usage: hub-envs untrust user/name@<40-hex sha>"


def main(argv: list[str]) -> int:
    """Remove the trust entries of the one ``user/name[@<sha>]`` in ``argv``.

    Args:
        argv: the command's arguments.

    Returns:
        The exit code: 0.

    Raises:
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    if any(a in ("-h", "--help") for a in argv):
        print(f"{USAGE}\nforget the trust entries of a repo: hub-envs untrust user/name[@<sha>]")
        return 0
    refs = [a for a in argv if not a.startswith("-")]
    if len(refs) != 1:
        raise ConfigError(USAGE)
    repo_id, sha = parse_repo_ref(refs[0])
    n = trust_list.untrust(repo_id, sha)
    print(f"Removed {n} trust entr{'y' if n == 1 else 'ies'} for {repo_id}.")
    return 0
