"""The policies a benchmark, an evaluation or a comparison runs: the seeded random policy, or a LeRobot checkpoint
at a pinned commit, loaded with its own consent (it is another repo than the env)."""

from __future__ import annotations

import glob
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from huggingface_hub import snapshot_download

from hub_envs._text import safe_text
from hub_envs.errors import ReproductionError, UntrustedCodeError
from hub_envs.repo import hub_io
from hub_envs.repo.format import is_commit_sha
from hub_envs.repo.refs import parse_repo_ref
from hub_envs.repo.trust_list import read_trust_list, snapshot_digest


def _processor_classes(path: str) -> list[str]:
    """The ``"class"`` entries of a checkpoint's ``policy_*processor.json``: what LeRobot's factory would import."""
    out = []
    for file in sorted(glob.glob(os.path.join(path, "*processor*.json"))):
        try:
            steps = json.loads(Path(file).read_text(encoding="utf-8")).get("steps", [])
        except (OSError, ValueError, AttributeError, RecursionError):
            continue
        out += [str(s["class"]) for s in steps if isinstance(s, dict) and isinstance(s.get("class"), str)]
    return out


def _check_policy_consent(
    repo_id: str, revision: str, path: str, trusted: Any, trust_policy_code: bool, digest: str, bound_to: str | None = None
) -> None:
    """A policy checkpoint is a second repo whose loading runs code (LeRobot's processor factory imports the
    classes its JSON names): the same gate as the env's, with its own consent. ``digest``: the downloaded files'
    (:func:`~hub_envs.repo.trust_list.snapshot_digest`); ``bound_to``: the digest consent was given for elsewhere (a Ray
    worker gets the driver's), other files are refused whatever ``trust_policy_code`` says."""
    if bound_to is not None and digest != bound_to:
        raise UntrustedCodeError(
            f"policy {repo_id}@{revision} holds files of content {digest[:16]}…, not the content {bound_to[:16]}… its consent "
            f"was given for; nothing of it was loaded. The endpoint (or the network path to it) serves other files under "
            f"this commit id than the ones that were consented to: do not run it."
        )
    if trust_policy_code or trusted.covers(repo_id, revision, digest):
        return
    classes = _processor_classes(path)
    raise UntrustedCodeError(
        f"benchmark policy {repo_id}@{revision} is another repo than the env, and loading it can run code"
        + (f" (LeRobot's processor factory would import {', '.join(safe_text(c) for c in classes)})" if classes else "")
        + f"; nothing of it was loaded. Consent to the env does not cover it. Read it in {path}, then pass "
        f"trust_policy_code=True (hub-envs reproduce --trust_policy_code=true) or trust this exact commit once:\n"
        f"  hub-envs trust {repo_id}@{revision}"
    )


def _checkpoint_policy(
    spec: dict[str, Any], loaded: Any, *, token: str | None = None, trust_policy_code: bool = False
) -> Callable[[Any, int], np.ndarray]:
    """A LeRobot pretrained policy at a pinned commit (``"checkpoint": "user/policy@<sha>"``), or in a local
    ``pretrained_model`` folder (``"path": ...``: the caller's own files, loaded without a consent check), as
    the rollout engine's ``(obs, t) -> action``."""
    local = spec.get("path")
    ref = spec.get("checkpoint") or spec.get("repo_id")
    if isinstance(local, str):
        ref = local
        if not (Path(local) / "config.json").is_file():
            raise ReproductionError(
                f"policy folder {local}: no config.json in it. Pass a LeRobot `pretrained_model` folder "
                "(e.g. outputs/train/checkpoints/last/pretrained_model) or a Hub repo id."
            )
    elif not isinstance(ref, str):
        raise ReproductionError(f'benchmark policy {spec!r}: a checkpoint policy needs "checkpoint": "user/policy@<sha>".')
    else:
        repo_id, revision = parse_repo_ref(ref)
        revision = spec.get("revision") or revision
        if not is_commit_sha(revision):
            raise ReproductionError(
                f"benchmark policy {ref!r} is not pinned to a commit: a benchmark result is only reproducible against the "
                f'exact weights. Declare it as "{repo_id}@<40-hex sha>".'
            )
    try:  # heavy: torch, lerobot's policies
        import torch  # heavy: torch
        from lerobot.configs.policies import PreTrainedConfig  # heavy: lerobot (torch)
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors  # heavy: lerobot (torch)
    except ImportError as exc:  # pragma: no cover - lerobot is a dependency
        raise ReproductionError(f"benchmark policy {ref!r} needs lerobot and torch: {exc}") from exc

    digest = None
    if isinstance(local, str):
        path, repo_id, revision = str(local), str(local), "local"
    else:
        trusted = read_trust_list()  # before the download, as load_env does
        with hub_io.translate_hub_errors(repo_id, revision):
            path = snapshot_download(repo_id, revision=revision, token=token)
        digest = snapshot_digest(Path(path))
        _check_policy_consent(repo_id, revision, path, trusted, trust_policy_code, digest, spec.get("content_digest"))
    torch.set_num_threads(1)  # see act(): identical results in every worker, no OpenMP pool across fork
    try:
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = "cpu"
        policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        policy.eval()
        if os.path.isfile(os.path.join(path, "policy_preprocessor.json")):
            pre, post = make_pre_post_processors(
                cfg, pretrained_path=path, preprocessor_overrides={"device_processor": {"device": "cpu"}}
            )
        else:
            pre, post = make_pre_post_processors(cfg)
    except Exception as exc:
        raise ReproductionError(
            f"benchmark policy {repo_id}@{revision}: cannot load it as a LeRobot policy: {type(exc).__name__}: {exc}"
        ) from exc

    task = str(getattr(loaded.config, "task", "") or "")

    def act(obs: Any, t: int) -> np.ndarray:
        if t == 0:
            # one thread: the same arithmetic in every process (and no OpenMP pool inherited across fork)
            torch.set_num_threads(1)
            policy.reset()
            torch.manual_seed(0)
        batch = policy_observation(obs, task)
        with torch.inference_mode():
            action = post(policy.select_action(pre(batch)))
        return action.detach().cpu().numpy()[0]

    act.content_digest = digest  # what a remote worker's copy must hold (remote_policy_spec)
    return act


def remote_policy_spec(spec: dict[str, Any], built: Any) -> dict[str, Any]:
    """The spec a remote (Ray) worker builds its own copy of a policy from, bound to the checkpoint content consent
    was given for here: a worker whose Hub serves other files refuses them.

    Args:
        spec: the policy's spec (:func:`policy_for`).
        built: the policy built here from it.

    Returns:
        ``spec`` with the checkpoint's ``content_digest``.
    """
    digest = getattr(built, "content_digest", None)
    return {**spec, "content_digest": digest} if digest is not None else dict(spec)


def policy_observation(env_observation: dict, task: str | None = "") -> dict:
    """What LeRobot's eval loop gives the policy for one (unbatched) env observation: the one conversion hub-envs uses
    (benchmarks, the env processors' dry run).

    Args:
        env_observation: an observation as the env returns it.
        task: the config's task text.

    Returns:
        LeRobot's ``preprocess_observation`` of it (images HWC uint8 -> CHW float in [0, 1], states float32, a batch
        axis) with ``"task"``.
    """
    from lerobot.envs.utils import preprocess_observation  # heavy: lerobot (torch)

    batched = {k: (np.asarray(v)[None] if not isinstance(v, dict) else v) for k, v in env_observation.items()}
    obs = preprocess_observation(batched)
    obs["task"] = [task or ""]
    return obs


def policy_for(spec: dict[str, Any], loaded: Any, token: str | None, trust_policy_code: bool = False) -> Any:
    """The policy a benchmark declares, built for ``loaded``'s env.

    Args:
        spec: the benchmark's ``policy``: ``{"type": "random"}``, or ``{"type": "lerobot", "checkpoint":
            "user/policy@<sha>"}`` (or ``"path"``: a local ``pretrained_model`` folder).
        loaded: the env (a :class:`~hub_envs.loading.loaded.LoadedEnv`: its config's task).
        token: the Hub token to download the checkpoint with.
        trust_policy_code: consent to load the checkpoint (another repo than the env).

    Returns:
        None for the seeded random policy, else the rollout engine's ``(obs, t) -> action``.

    Raises:
        ReproductionError: an unknown policy type, an unpinned checkpoint, or one LeRobot cannot load.
        UntrustedCodeError: no consent to load the checkpoint.
    """
    kind = str(spec.get("type", "")).lower()
    if kind == "random":
        return None
    if kind in ("lerobot", "checkpoint", "pretrained"):
        return _checkpoint_policy(spec, loaded, token=token, trust_policy_code=trust_policy_code)
    raise ReproductionError(
        f'benchmark policy type {spec.get("type")!r} is not supported; hub-envs reproduces "random" and '
        f'"lerobot" (a LeRobot pretrained policy pinned as "checkpoint": "user/policy@<sha>").'
    )
