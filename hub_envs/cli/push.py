"""``hub-envs push`` / ``push_env``: validate an env folder, generate its dataset and card, publish it in one commit."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hub_envs.cli.argv import parse_config
from hub_envs.errors import ConfigError

ARGV = True  # main(argv, prog): the --config.<field> flags are split off before draccus parses the rest


@dataclass
class Config:
    """Validate a local env folder, generate its dataset and card, publish it in one commit."""

    env_dir: Path | None = None  # the env folder to publish (its pyproject.toml, code and config)
    repo_id: str | None = None  # where to publish it: user/name on the Hub; may come first, without the flag
    episodes: int = 10  # random-action episodes of the dataset; episode i resets with seed + i
    seed: int = 0  # the first episode's seed, and the checks'
    private: bool = False  # create the repo private (an existing repo keeps its visibility; the dataset repo follows it)
    tag: str | None = None  # a tag of your own for the commit (refused if it names another commit)
    workers: int = 0  # 0: as many as useful on this machine (local), the cluster's CPUs (ray)
    backend: str = "local"  # where the episodes run: local (this machine's processes) or ray (a Ray cluster)
    ray_address: str | None = None  # --backend=ray: the cluster; default $RAY_ADDRESS, else a local Ray for the run
    out: Path | None = None  # --backend=ray: keep finished shards here; the same push started again skips them
    commit_message: str | None = None  # the commit's message; default: push_env: <name> <version> (<n> episodes, seed <s>)
    determinism_steps: int | None = None  # cap of the determinism check; default: a whole episode (two seeds)
    force: bool = False  # rebuild even when main already holds this code, config, seeds and versions
    video: bool | None = None  # camera features as MP4 (LeRobot's encoder); default: true when the env has cameras
    video_gop: int | None = None  # the videos' keyframe interval; default 10 (about 1/5 of the PNG size), LeRobot's is 2
    dataset_repo: bool = True  # also publish the dataset as the dataset repo of the same name (LeRobotDataset(repo_id))


def main(argv: list[str], prog: str = "hub-envs push") -> int:
    """Publish an env folder: :class:`Config`'s flags, plus ``--config.<field>=<value>`` for a variant (a field of the env's EnvConfig).

    Args:
        argv: the command's arguments (a positional repo id is ``--repo_id``).
        prog: how usage lines and messages name the command (``push_env`` or ``hub-envs push``).

    Returns:
        The exit code: 0.

    Raises:
        UsageError: a flag push does not have (the closest named), or a repo id given twice, differently.
        HubEnvsError: what failed (the CLI prints it as one message, exit code 1).
    """
    variant, rest = config_flags(argv)
    if any(a in ("-h", "--help") for a in rest):
        print("Config variants: --config.<field>=<value> sets a field of the env's EnvConfig before publishing.\n")
    return push(parse_config(prog, Config, rest, positional=("repo_id",)), variant)


def push(config: Config, variant: dict) -> int:
    """Publish ``config.env_dir`` (with the ``variant``'s config fields) to ``config.repo_id`` and print the result.

    Args:
        config: the command's flags.
        variant: ``{field: value}`` from the ``--config.<field>=<value>`` flags.

    Returns:
        0.

    Raises:
        ConfigError: ``--env_dir`` or ``--repo_id`` missing.
        HubEnvsError: what push_env raised.
    """
    from hub_envs.publishing.push import push_env  # heavy: lerobot, torch (after the flags are parsed)

    if config.env_dir is None or config.repo_id is None:
        raise ConfigError("push_env needs --env_dir=PATH and --repo_id=user/name.")
    result = push_env(
        config.env_dir,
        config.repo_id,
        episodes=config.episodes,
        seed=config.seed,
        private=config.private,
        tag=config.tag,
        workers=config.workers or None,
        backend=config.backend,
        ray_address=config.ray_address,
        out=config.out,
        commit_message=config.commit_message,
        determinism_steps=config.determinism_steps,
        force=config.force,
        video=config.video,
        video_gop=config.video_gop,
        dataset_repo=config.dataset_repo,
        config=variant or None,
    )
    print(result.summary())
    return 0


def config_flags(argv: list[str]) -> tuple[dict, list[str]]:
    """Split ``--config.<field>[.<sub>]=<value>`` flags (a config variant, as LeRobot's ``--env.<field>``) from the
    others.

    Args:
        argv: the command's arguments.

    Returns:
        ``({field: value or {sub: value}}, the other arguments)``.

    Raises:
        ConfigError: a ``--config.`` flag without a field or a value, or a field given both a value and fields.

    >>> config_flags(["--repo_id=a/b", "--config.obs_type=pixels_agent_pos", "--config.cam.width=64"])
    ({'obs_type': 'pixels_agent_pos', 'cam': {'width': '64'}}, ['--repo_id=a/b'])
    """
    values: dict = {}
    rest = []
    for arg in argv:
        if not arg.startswith("--config."):
            rest.append(arg)
            continue
        path, sep, value = arg[len("--config.") :].partition("=")
        if not sep or not path or "" in path.split("."):
            raise ConfigError(
                f"{arg}: write a config field as --config.<field>=<value>, e.g. --config.obs_type=pixels_agent_pos."
            )
        *parents, leaf = path.split(".")
        node = values
        for name in parents:
            node = node.setdefault(name, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{arg}: --config.{name} was already given a value; it cannot also have fields.")
        node[leaf] = value
    return values, rest
