"""The ``hub-envs`` command line (and the ``push_env`` console script).

Flags are draccus-style, as in LeRobot's CLIs: ``--key=value`` (``--key value`` works too).

    hub-envs serve --root=./hub-data --port=8000 [--token=T] [--max_body_mb=2048] [--max_line_mb=16] [--max_lfs_mb=51200]
    push_env --env_dir=envs/pendulum --repo_id=user/pendulum-lerobot [--episodes=10] [--seed=0] [--tag=v1] [--video=false] [--video_gop=2] [--backend=ray] [--dataset_repo=false]
    hub-envs load --repo_id=user/pendulum-lerobot@<sha> [--trust_remote_code=true] [--isolation=process] [--sandbox=true] [--recheck=true]
    hub-envs trust user/pendulum-lerobot@<sha>
    hub-envs reproduce --repo_id=user/pendulum-lerobot --revision=<sha> --trust_remote_code=true [--attest=true] [--backend=ray]
    hub-envs attestations --repo_id=user/pendulum-lerobot [--verify=true --allowed_signers=FILE]
    hub-envs compare --repo_id=user/pendulum-lerobot@<sha> --policies=random,path/to/pretrained_model [--episodes=20]
    hub-envs evaluate --repo_id=user/pendulum-lerobot@<sha> --trust_remote_code=true --episodes=100 [--backend=ray]
    hub-envs train --env.type=hub --env.repo_id=user/pendulum-lerobot --env.revision=<sha> --policy.type=act ...
    hub-envs eval --env.type=hub --env.repo_id=user/pendulum-lerobot --env.revision=<sha> --policy.path=...

Every hub-envs error is printed as one message (what failed, what to do next) with exit code 1.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import draccus

from hub_envs.cli.flags import EnvFlags, call_with_flags, check_repo_flags


@dataclass
class ServeArgs:
    """Run the loopback Hub-protocol server."""

    root: Path = Path("./hub-data")
    host: str = "127.0.0.1"
    port: int = 8000
    token: str | None = None
    max_body_mb: float | None = None  # largest request body; default: $HUB_ENVS_SERVER_MAX_BODY_MB, else 2048
    max_line_mb: float | None = None  # largest commit line (one base64 file); default: $HUB_ENVS_SERVER_MAX_LINE_MB, else 16
    max_lfs_mb: float | None = None  # largest LFS file; default: $HUB_ENVS_SERVER_MAX_LFS_MB, else 51200 (the Hub's 50 GB)
    header_timeout: float | None = (
        None  # seconds to send a request head, then 408; default: $HUB_ENVS_SERVER_HEADER_TIMEOUT, else 20
    )
    max_connections: int | None = None  # connections open at once, then 503; default: $HUB_ENVS_SERVER_MAX_CONNECTIONS, else 1000


@dataclass
class PushArgs:
    """Validate a local env folder, generate its dataset and card, publish it in one commit."""

    env_dir: Path | None = None
    repo_id: str | None = None
    episodes: int = 10
    seed: int = 0
    private: bool = False
    tag: str | None = None
    workers: int = 0  # 0: as many as useful on this machine (local), the cluster's CPUs (ray)
    backend: str = "local"  # where the episodes run: local (this machine's processes) or ray (a Ray cluster)
    ray_address: str | None = None  # --backend=ray: the cluster; default $RAY_ADDRESS, else a local Ray for the run
    out: Path | None = None  # --backend=ray: keep finished shards here; the same push started again skips them
    commit_message: str | None = None
    determinism_steps: int | None = None  # cap of the determinism check; default: a whole episode (two seeds)
    force: bool = False  # rebuild even when main already holds this code, config, seeds and versions
    video: bool | None = None  # camera features as MP4 (LeRobot's encoder); default: true when the env has cameras
    video_gop: int | None = None  # the videos' keyframe interval; default 10 (about 1/5 of the PNG size), LeRobot's is 2
    dataset_repo: bool = True  # also publish the dataset as the dataset repo of the same name (LeRobotDataset(repo_id))


@dataclass
class LoadArgs(EnvFlags):
    """Load an env repo, run its checks, and print what was loaded (the three-way table)."""

    check: bool = True
    fingerprint: str = "error"
    recheck: bool = False  # run the checks even if they passed before with the same packages (a cached verdict)
    json: bool = False


def serve(args: ServeArgs) -> int:
    from hub_envs.errors import MissingRequirementsError

    try:
        from hub_envs.server import run
    except ModuleNotFoundError as exc:
        if exc.name not in ("starlette", "uvicorn", "markdown_it", "pygments"):
            raise
        raise MissingRequirementsError(
            f"hub-envs serve needs {exc.name}, which is not installed. Install the server extra: pip install 'hub-envs[server]'"
        ) from None

    run(**dataclasses.asdict(args))  # ServeArgs' fields are run()'s keywords
    return 0


def config_flags(argv: list[str]) -> tuple[dict, list[str]]:
    """Split ``--config.<field>[.<sub>]=<value>`` flags (a config variant, as LeRobot's ``--env.<field>``) from
    the others: ``({field: value or {sub: value}}, the other flags)``.

    >>> config_flags(["--repo_id=a/b", "--config.obs_type=pixels_agent_pos", "--config.cam.width=64"])
    ({'obs_type': 'pixels_agent_pos', 'cam': {'width': '64'}}, ['--repo_id=a/b'])
    """
    from hub_envs.errors import ConfigError

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


def push_command(argv: list[str]) -> int:
    """``push_env`` / ``hub-envs push``: PushArgs' flags, plus ``--config.<field>=<value>`` for a variant."""
    config, rest = config_flags(argv)
    if any(a in ("-h", "--help") for a in rest):
        print("Config variants: --config.<field>=<value> sets a field of the env's EnvConfig before publishing.\n")
    return push(draccus.parse(config_class=PushArgs, args=rest), config=config)


def push(args: PushArgs, *, config: dict | None = None) -> int:
    from hub_envs.errors import ConfigError
    from hub_envs.publishing.push import push_env

    if args.env_dir is None or args.repo_id is None:
        raise ConfigError("push_env needs --env_dir=PATH and --repo_id=user/name.")
    result = call_with_flags(push_env, args, args.env_dir, args.repo_id, workers=args.workers or None, config=config or None)
    print(result.summary())
    return 0


def load(args: LoadArgs) -> int:
    from hub_envs.errors import ConfigError
    from hub_envs.loading.load import load_env

    if args.repo_id is None:
        raise ConfigError("hub-envs load needs --repo_id=user/name[@revision] (or a local folder).")
    loaded = call_with_flags(load_env, args, args.repo_id)
    if args.json:
        print(
            json.dumps(
                {
                    "repo_id": loaded.repo_id,
                    "revision": loaded.revision,
                    "gym_id": loaded.gym_id,
                    "env_type": loaded.env_type,
                    "path": str(loaded.path),
                    "isolation": _isolation_text(loaded),
                    "report": loaded.report.to_dict(),
                },
                indent=2,
            )
        )
        return 0
    print(f"Loaded {loaded.repo_id} at {loaded.revision}")
    print(f"  gym id:      {loaded.gym_id}")
    print(f"  --env.type:  {loaded.env_type}")
    print(f"  snapshot:    {loaded.path}")
    print(f"  runs:        {_isolation_text(loaded)}")
    print(f"  integrity:   {loaded.report.integrity}")
    print(f"  trust:       {loaded.report.trust}")
    print(f"  fingerprint: {loaded.report.fingerprint}")
    if loaded.report.features is not None:
        print("  three-way feature check (declared / live / dataset):")
        print("    " + loaded.report.features.table().replace("\n", "\n    "))
    return 0


def _isolation_text(loaded) -> str:
    iso = loaded.isolation
    if iso is None:
        return "in this process"
    return "in a sandboxed worker process" if iso.sandbox else "in a worker process"


def _trust_cmd(argv: list[str], *, remove: bool) -> int:
    usage = f"usage: hub-envs {'untrust' if remove else 'trust'} user/name@<40-hex sha>"
    if any(a in ("-h", "--help") for a in argv):
        print(f"{usage}\n{SUMMARIES['untrust' if remove else 'trust']}")
        return 0
    from hub_envs.errors import ConfigError
    from hub_envs.repo import hub_io, trust_list

    refs = [a for a in argv if not a.startswith("-")]
    if len(refs) != 1:
        raise ConfigError(usage)
    repo_id, sha = hub_io.parse_repo_ref(refs[0])
    if remove:
        n = trust_list.untrust(repo_id, sha)
        print(f"Removed {n} trust entr{'y' if n == 1 else 'ies'} for {repo_id}.")
        return 0
    if sha is None or not hub_io.is_commit_sha(sha):
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


COMMANDS = {
    "serve": (ServeArgs, serve),
    "push": push_command,
    "load": (LoadArgs, load),
}
RAW_COMMANDS = {
    "trust": lambda argv: _trust_cmd(argv, remove=False),
    "untrust": lambda argv: _trust_cmd(argv, remove=True),
}
#: Commands whose modules import lerobot and torch: imported only when the command runs, never for
#: ``--help`` or the light commands above (each module has a ``CLI_COMMANDS`` table).
LAZY_COMMANDS = {
    "reproduce": "hub_envs.operations.reproduce",
    "evaluate": "hub_envs.operations.evaluate",
    "diff": "hub_envs.operations.diff",
    "attestations": "hub_envs.repo.attestations",
    "compare": "hub_envs.operations.compare",
    "train": "hub_envs.lerobot.bridge",
    "eval": "hub_envs.lerobot.bridge",
}
SUMMARIES = {
    "serve": "run the loopback Hub-protocol server",
    "push": "validate an env folder, generate its dataset and card, publish it in one commit (also: push_env)",
    "load": "load an env repo, run its checks, print the three-way feature table",
    "trust": "trust one commit of a repo: hub-envs trust user/name@<sha>",
    "untrust": "forget the trust entries of a repo: hub-envs untrust user/name[@<sha>]",
    "reproduce": "re-run what a repo recorded (dataset replay, benchmarks, fingerprint) and report",
    "evaluate": "a policy over N seeded episodes, locally or on a Ray cluster (--backend=ray)",
    "diff": "what changed between two revisions (files, manifest, spaces) and where their behaviour diverges",
    "attestations": "a repo's reproduction attestations (merged and in open PRs): env revision x stack -> verdict",
    "compare": "evaluate policies (LeRobot checkpoints, random) on the same seeds: rates, CIs, paired difference",
    "train": "LeRobot's lerobot-train with a hub env (--env.type=hub --env.repo_id=...)",
    "eval": "LeRobot's lerobot-eval with a hub env (--env.type=hub --env.repo_id=...)",
}


def _lazy_command(name: str):
    import importlib

    return importlib.import_module(LAZY_COMMANDS[name]).CLI_COMMANDS[name]


def _usage() -> str:
    width = max(map(len, SUMMARIES))
    lines = "\n".join(f"  {name:<{width}}  {SUMMARIES[name]}" for name in SUMMARIES)
    return (
        f"usage: hub-envs <command> [--flag=value ...]\n\ncommands:\n{lines}\n\n"
        f"Run `hub-envs <command> --help` for the flags of one command."
    )


def _format_warning(message, category, filename, lineno, line=None) -> str:
    return f"warning: {message}\n"


#: what an interrupted command leaves behind, said after "interrupted (Ctrl-C)"
INTERRUPTED_NOTES = {
    "push": " push_env builds the repo in a temporary folder (now removed) and makes its one commit only after every "
    "episode is written: an interrupted build published nothing. Run the same command again (on Ray with --out=DIR, "
    "the finished shards are kept and skipped).",
}


def run_command(name: str, argv: list[str]) -> int:
    import warnings

    from hub_envs.errors import HubEnvsError

    warnings.formatwarning = _format_warning  # a CLI user needs the message, not our source line

    if name not in COMMANDS and name not in RAW_COMMANDS and name not in LAZY_COMMANDS:
        print(f"hub-envs: unknown command {name!r}\n{_usage()}", file=sys.stderr)
        return 2
    try:
        check_repo_flags(argv)  # before draccus, which drops a trailing newline of a flag's value
        if name in RAW_COMMANDS:
            return int(RAW_COMMANDS[name](argv) or 0)
        entry = COMMANDS[name] if name in COMMANDS else _lazy_command(name)
        if callable(entry):  # a raw command: parses argv itself (hub-envs train/eval hand it to LeRobot's parser)
            return int(entry(argv) or 0)
        args_cls, func = entry
        args = draccus.parse(config_class=args_cls, args=argv)
        return int(func(args) or 0)
    except HubEnvsError as e:
        print(f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # the work in flight (worker processes, Ray tasks) was stopped on the way out
        note = INTERRUPTED_NOTES.get(name, "")
        print(f"\nhub-envs {name}: interrupted (Ctrl-C); the work in flight was stopped.{note}", file=sys.stderr)
        return 130  # 128 + SIGINT, as a shell reports it


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(_usage(), file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    return run_command(argv[0], argv[1:])


def push_env_main(argv: list[str] | None = None) -> int:
    """The ``push_env`` console script: ``push_env --env_dir=... --repo_id=...``."""
    return run_command("push", list(sys.argv[1:] if argv is None else argv))
