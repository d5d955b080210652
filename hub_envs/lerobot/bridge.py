"""``hub-envs train`` and ``hub-envs eval``: LeRobot's own training and evaluation with a hub env chosen by flag, the
repo loaded before LeRobot parses, provenance written beside the results.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import re
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hub_envs._compat import missing_training_packages, video_backend
from hub_envs.dataset.reader import dataset_fingerprint, read_info
from hub_envs.errors import ConfigError, HubEnvsError, MissingRequirementsError
from hub_envs.harness.provenance import package_versions
from hub_envs.repo import hub_io
from hub_envs.repo.refs import check_repo_flags, check_repo_id

PROVENANCE_FILE = "hub_envs_provenance.json"
_PER_REPO_RE = re.compile(r"(?P<repo>[^@\s]+/[^@\s]+)@(?P<prefix>[0-9a-f]{7,40})")  # fullmatch: no trailing newline
_CONSUMED = ("repo_id", "revision", "trust_remote_code", "fingerprint", "check")


# --- argv -------------------------------------------------------------------------------------


def flag(argv: list[str], name: str) -> str | None:
    """The value of a ``--name=value`` flag.

    Args:
        argv: the arguments.
        name: the flag's name.

    Returns:
        Its value (the last one wins), else None.
    """
    prefix = f"--{name}="
    values = [a[len(prefix) :] for a in argv if a.startswith(prefix)]
    return values[-1] if values else None


def _drop(argv: list[str], names: tuple[str, ...]) -> list[str]:
    return [a for a in argv if not any(a.startswith(f"--{n}=") or a == f"--{n}" for n in names)]


def _true(value: str | None) -> bool:
    return value is not None and value.strip().lower() in ("1", "true", "yes", "on")


def _resolve_short_sha(repo_id: str, prefix: str) -> str:
    """The full sha of ``repo_id`` starting with ``prefix``: from the local cache, else the Hub's commit list."""
    snapshots = hub_io.cache_snapshots_dir(repo_id)
    cached = sorted(p.name for p in snapshots.glob(f"{prefix}*")) if snapshots.is_dir() else []
    if len(cached) == 1:
        return cached[0]
    if not hub_io.offline():
        with hub_io.translate_hub_errors(repo_id, prefix):
            commits = [c.commit_id for c in hub_io.api().list_repo_commits(repo_id, repo_type=hub_io.REPO_TYPE)]
        matches = [c for c in commits if c.startswith(prefix)]
        if len(matches) == 1:
            return matches[0]
    raise ConfigError(
        f"--env.type={repo_id}@{prefix}: no single commit of {repo_id} starts with {prefix} "
        f"({'in the local cache' if hub_io.offline() else 'locally or on the Hub'}). "
        f"Add --env.revision=<the full 40-hex sha>, or use --env.type=hub --env.repo_id={repo_id} --env.revision=<sha>."
    )


def prepare_argv(argv: list[str], *, command: str) -> tuple[list[str], Any]:
    """Register hub-envs' choices and hooks in LeRobot, and load the env the flags name before LeRobot parses them.

    Args:
        argv: LeRobot's flags (``--env.type=hub --env.repo_id=...``, or a per-repo ``--env.type=user/name@<sha12>``).
        command: ``"train"``, ``"eval"`` or ``"plugin"`` (LeRobot's own CLI).

    Returns:
        ``(argv for LeRobot, the LoadedEnv or None)``.

    Raises:
        ConfigError: a flag that names no repo or a malformed one.
        UntrustedCodeError: no consent to run the repo's code.
        HubEnvsError: as :func:`hub_envs.load_env`.
    """
    from hub_envs.lerobot.env import HUB_CHOICE, install_hooks, load_cached, set_cli_consent  # heavy: lerobot

    install_hooks()
    argv = list(argv)
    check_repo_flags(argv)  # LeRobot's draccus drops a trailing newline of a flag's value: the raw text first
    env_type = flag(argv, "env.type")
    top_trust = command in ("eval", "plugin") and _true(flag(argv, "trust_remote_code"))
    trust = _true(flag(argv, "env.trust_remote_code")) or top_trust
    set_cli_consent(trust)  # the command line's consent, and only it: a --config_path file's value is ignored
    fingerprint = flag(argv, "env.fingerprint") or "error"
    check = flag(argv, "env.check")
    check = True if check is None else _true(check)
    loaded = None
    if env_type == HUB_CHOICE:
        repo_id = flag(argv, "env.repo_id")
        if not repo_id:
            raise ConfigError("--env.type=hub needs --env.repo_id=user/name (and --env.revision=<sha> to pin it).")
        loaded = load_cached(
            repo_id,
            flag(argv, "env.revision"),
            trust_remote_code=trust,
            fingerprint=fingerprint,
            check=check,
            isolation=flag(argv, "env.isolation") or "none",
            sandbox=_true(flag(argv, "env.sandbox")),
            versions=flag(argv, "env.versions") or "current",
        )
    elif env_type and _PER_REPO_RE.fullmatch(env_type):
        m = _PER_REPO_RE.fullmatch(env_type)
        repo_id = flag(argv, "env.repo_id") or check_repo_id(m["repo"], what="--env.type: repo id")
        revision = flag(argv, "env.revision")
        if revision is None:
            revision = _resolve_short_sha(repo_id, m["prefix"])
        elif not revision.startswith(m["prefix"]):
            raise ConfigError(f"--env.type={env_type} names commit {m['prefix']}..., but --env.revision={revision}.")
        loaded = load_cached(repo_id, revision, trust_remote_code=trust, fingerprint=fingerprint, check=check)
        if loaded.env_type != env_type:
            raise ConfigError(
                f"{repo_id}@{loaded.revision} registers the choice {loaded.env_type!r}, not {env_type!r}. "
                f"Use --env.type={loaded.env_type}."
            )
        argv = _drop(argv, tuple(f"env.{n}" for n in _CONSUMED))  # not fields of the repo's own config
    if command == "train" and loaded is not None and loaded.dataset_root is not None:
        ds_repo = flag(argv, "dataset.repo_id")
        if ds_repo is None:
            argv += [f"--dataset.repo_id={loaded.repo_id}", f"--dataset.root={loaded.dataset_root}"]
        elif ds_repo == loaded.repo_id and flag(argv, "dataset.root") is None:
            argv.append(f"--dataset.root={loaded.dataset_root}")
        if flag(argv, "dataset.video_backend") is None and _has_video(loaded.dataset_meta_root):
            # LeRobot 0.4 defaults to torchcodec whenever it is installed, even when it cannot load

            argv.append(f"--dataset.video_backend={video_backend()}")
    return argv, loaded


def portable_argv(argv: list[str], loaded: Any) -> list[str]:
    """The flags as typed (``argv``, before :func:`prepare_argv`), as another machine can run them again: the env
    pinned to the commit that ran (``--env.revision=<sha>``, whatever branch or short sha was typed), and no path into
    this machine's snapshot of it (the ``--dataset.root`` of the env's own dataset, which hub-envs adds again from
    the repo id and sha). What a provenance file records as ``command``.

    >>> class Loaded: revision, path, is_local = "ab" * 20, Path("/cache/snapshots/ab"), False
    >>> portable_argv(["--env.type=hub", "--env.repo_id=u/e", "--env.revision=main", "--dataset.root=/cache/snapshots/ab/dataset"], Loaded)
    ['--env.type=hub', '--env.repo_id=u/e', '--env.revision=abababababababababababababababababababab']
    """
    if loaded is None or loaded.is_local:
        return list(argv)
    snapshot = Path(loaded.path)
    out = []
    for arg in argv:
        if arg.startswith("--dataset.root=") and Path(arg.split("=", 1)[1]).is_relative_to(snapshot):
            continue
        if arg.startswith("--env.revision=") or arg == "--env.revision":
            continue
        out.append(arg)
    return [*out, f"--env.revision={loaded.revision}"]


def _has_video(dataset_meta_root) -> bool:
    if dataset_meta_root is None:
        return False
    features = read_info(dataset_meta_root)["features"]
    return any(isinstance(ft, dict) and ft.get("dtype") == "video" for ft in features.values())


@contextlib.contextmanager
def _sys_argv(argv: list[str], prog: str) -> Iterator[None]:
    """LeRobot's parser and its configs read ``sys.argv`` (``--policy.path``), so set it for the call."""
    saved = sys.argv
    sys.argv = [prog, *argv]
    try:
        yield
    finally:
        sys.argv = saved


def _hub_envs_cause(error: BaseException) -> HubEnvsError | None:
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, HubEnvsError):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _run_wrapped(config_class: type, body: Callable[[Any], Any], argv: list[str], prog: str):
    """Parse ``argv`` with LeRobot's own ``parser.wrap`` into ``config_class`` and call ``body(cfg)``."""
    from lerobot.configs import parser  # heavy: lerobot (torch)

    def entry(cfg):
        return body(cfg)

    entry.__annotations__ = {"cfg": config_class}  # parser.wrap reads the config class from the annotation
    wrapped = parser.wrap()(entry)
    with _sys_argv(argv, prog):
        try:
            return wrapped()
        except Exception as e:
            cause = _hub_envs_cause(e)
            if cause is not None and cause is not e:
                raise cause from None
            raise


# --- provenance -------------------------------------------------------------------------------


def _json_default(value):
    if isinstance(value, Path):
        return str(value)
    return str(value)


def env_provenance(env_cfg_or_hub) -> dict[str, Any] | None:
    """What identifies the env a LeRobot config names.

    Args:
        env_cfg_or_hub: LeRobot's ``cfg.env``.

    Returns:
        The repo, sha, digests, config values and processors; None for a config that is not a hub env's.
    """
    from hub_envs.envcode.envconfig import encode_config  # heavy: lerobot (its EnvConfig)
    from hub_envs.lerobot.env import loaded_for  # heavy: lerobot (its EnvConfig)

    found = loaded_for(env_cfg_or_hub)
    if found is None:
        return None
    loaded, cfg = found
    from hub_envs.loading.processors import specs_for  # heavy: torch, lerobot's processors

    m = loaded.manifest
    return {
        "repo_id": loaded.repo_id,
        "revision": loaded.revision,
        "requested_revision": loaded.requested_revision,
        "load_line": loaded.load_line(),
        "env_type": loaded.env_type,
        "gym_id": loaded.gym_id,
        "content_digest": m.content_digest,
        "code_digest": m.code_digest,
        "dataset_fingerprint": m.dataset.get("fingerprint"),
        "golden_fingerprint": m.fingerprint.get("digest") if isinstance(m.fingerprint, dict) else None,
        "config": encode_config(cfg),
        "processors": [s.to_dict() for s in specs_for(loaded)],
        "published_with": dict(m.versions),
    }


def dataset_provenance(repo_id: str | None, root: str | Path | None, revision: str | None, env: dict | None) -> dict[str, Any]:
    """What identifies the dataset a run trained on.

    Args:
        repo_id: LeRobot's ``--dataset.repo_id``.
        root: ``--dataset.root``.
        revision: ``--dataset.revision``.
        env: :func:`env_provenance` of the run's env (to say whether it is that env's own dataset).

    Returns:
        The repo id, root, revision and fingerprint (and ``is_env_dataset``).
    """
    out: dict[str, Any] = {"repo_id": repo_id, "root": str(root) if root else None, "revision": revision, "fingerprint": None}
    if root and (Path(root) / "meta" / "info.json").is_file():
        out["fingerprint"] = dataset_fingerprint(root)
    if env is not None and out["fingerprint"] is not None:
        out["is_env_dataset"] = out["fingerprint"] == env.get("dataset_fingerprint")
    return out


def _versions() -> dict[str, str]:
    return package_versions()


def _policy_training(policy_path: Path | None) -> dict[str, Any] | None:
    """What the policy's checkpoint says about its training: hub-envs' sidecar, else LeRobot's train_config.json."""
    if policy_path is None or not Path(policy_path).is_dir():
        return None
    sidecar = Path(policy_path) / PROVENANCE_FILE
    if sidecar.is_file():
        return json.loads(sidecar.read_text(encoding="utf-8"))
    train_config = Path(policy_path) / "train_config.json"
    if train_config.is_file():
        data = json.loads(train_config.read_text(encoding="utf-8"))
        ds = data.get("dataset") or {}
        return {
            "dataset": dataset_provenance(ds.get("repo_id"), ds.get("root"), ds.get("revision"), None),
            "steps": data.get("steps"),
            "seed": data.get("seed"),
        }
    return None


def _write_json(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_json_default) + "\n", encoding="utf-8")


def train_provenance(cfg, argv: list[str]) -> dict[str, Any]:
    """What ``hub-envs train`` records beside the checkpoints.

    Args:
        cfg: LeRobot's ``TrainPipelineConfig``.
        argv: the command's flags (:func:`portable_argv`).

    Returns:
        The env, dataset and policy provenance, the command and the package versions.
    """
    env = env_provenance(cfg.env) if cfg.env is not None else None
    return {
        "hub_envs_provenance": 1,
        "command": ["hub-envs", "train", *argv],
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "env": env,
        "dataset": dataset_provenance(cfg.dataset.repo_id, cfg.dataset.root, cfg.dataset.revision, env),
        "policy": {"type": cfg.policy.type if cfg.policy else None},
        "steps": cfg.steps,
        "seed": cfg.seed,
        "output_dir": str(cfg.output_dir),
        "versions": _versions(),
    }


def eval_provenance(cfg, argv: list[str]) -> dict[str, Any]:
    """What ``hub-envs eval`` records in ``eval_info.json``.

    Args:
        cfg: LeRobot's ``EvalPipelineConfig``.
        argv: the command's flags (:func:`portable_argv`).

    Returns:
        The env and policy provenance (the training's, when the checkpoint has it), the command and the package versions.
    """
    env = env_provenance(cfg.env)
    policy_path = getattr(cfg.policy, "pretrained_path", None) if cfg.policy else None
    return {
        "hub_envs_provenance": 1,
        "command": ["hub-envs", "eval", *argv],
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "env": env,
        "policy": {
            "type": cfg.policy.type if cfg.policy else None,
            "path": str(policy_path) if policy_path else None,
            "training": _policy_training(Path(policy_path) if policy_path else None),
        },
        "eval": {"n_episodes": cfg.eval.n_episodes, "batch_size": cfg.eval.batch_size, "seed": cfg.seed},
        "output_dir": str(cfg.output_dir),
        "versions": _versions(),
    }


# --- the commands -----------------------------------------------------------------------------


def _forgets_cli_consent(command: Callable[[list[str]], int]) -> Callable[[list[str]], int]:
    """The command line's consent lasts for that command only (``hub-envs train`` may run inside a Python process)."""

    @functools.wraps(command)
    def run(argv: list[str]) -> int:
        from hub_envs.lerobot.env import set_cli_consent  # heavy: lerobot (its EnvConfig)

        try:
            return command(argv)
        finally:
            set_cli_consent(None)

    return run


@_forgets_cli_consent
def run_train(argv: list[str]) -> int:
    """``hub-envs train``: LeRobot's ``lerobot-train`` with ``argv``, a hub env's repo prepared first, provenance
    written beside the checkpoints.

    Args:
        argv: lerobot-train's flags (``--env.type=hub --env.repo_id=...``).

    Returns:
        0 (LeRobot's own errors propagate; hub-envs' are :class:`~hub_envs.errors.HubEnvsError` s).

    Raises:
        MissingRequirementsError: LeRobot's training extra is not installed.
    """
    missing = missing_training_packages()
    if missing:
        raise MissingRequirementsError(
            f"hub-envs train runs LeRobot's training loop, which needs {', '.join(missing)} (LeRobot's 'training' extra). "
            f"Install it: pip install 'lerobot[training]'  (or: pip install 'hub-envs[train]')"
        )
    typed = list(argv)
    argv, loaded = prepare_argv(argv, command="train")
    from lerobot.configs.train import TrainPipelineConfig  # heavy: lerobot (torch)
    from lerobot.scripts.lerobot_train import train  # heavy: lerobot (torch)
    from lerobot.utils.import_utils import register_third_party_plugins  # heavy: lerobot (torch)

    register_third_party_plugins()

    def body(cfg):
        train(cfg)  # LeRobot's own training loop (cfg.validate() runs inside)
        prov = train_provenance(cfg, portable_argv(typed, loaded))
        _write_json(Path(cfg.output_dir) / PROVENANCE_FILE, prov)
        for model_dir in sorted(Path(cfg.output_dir).glob("checkpoints/*/pretrained_model")):
            if not model_dir.parent.is_symlink():
                _write_json(model_dir / PROVENANCE_FILE, prov)
        print(f"hub-envs: wrote {Path(cfg.output_dir) / PROVENANCE_FILE}")

    _run_wrapped(TrainPipelineConfig, body, argv, "hub-envs train")
    return 0


@_forgets_cli_consent
def run_eval(argv: list[str]) -> int:
    """``hub-envs eval``: LeRobot's ``lerobot-eval`` with ``argv``, a hub env's repo prepared first, provenance written
    into its ``eval_info.json``.

    Args:
        argv: lerobot-eval's flags (``--env.type=hub --env.repo_id=...``).

    Returns:
        0 (LeRobot's own errors propagate; hub-envs' are :class:`~hub_envs.errors.HubEnvsError` s).
    """
    typed = list(argv)
    argv, loaded = prepare_argv(argv, command="eval")
    from lerobot.configs.eval import EvalPipelineConfig  # heavy: lerobot (torch)
    from lerobot.scripts.lerobot_eval import eval_main  # heavy: lerobot (torch)
    from lerobot.utils.import_utils import register_third_party_plugins  # heavy: lerobot (torch)
    from lerobot.utils.utils import init_logging  # heavy: lerobot (torch)

    init_logging()
    register_third_party_plugins()

    def body(cfg):
        eval_main(cfg)  # LeRobot's own eval loop; writes eval_info.json
        prov = eval_provenance(cfg, portable_argv(typed, loaded))
        out = Path(cfg.output_dir)
        _write_json(out / PROVENANCE_FILE, prov)
        info_path = out / "eval_info.json"
        if info_path.is_file():
            info = json.loads(info_path.read_text(encoding="utf-8"))
            info["provenance"] = prov
            _write_json(info_path, info)
        print(f"hub-envs: results with provenance in {info_path}")

    _run_wrapped(EvalPipelineConfig, body, argv, "hub-envs eval")
    return 0
