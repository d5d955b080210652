"""Env processors: the LeRobot ``ProcessorStep`` s an env repo declares (``[[tool.hub-envs.processors]]``) to run between
the env and the policy in LeRobot's eval loop: parsed, built and dry-run.

Example:
    >>> from hub_envs.loading.processors import parse_declarations
    >>> [s.stage for s in parse_declarations([{"name": "clip_action", "stage": "post"}], where="hub_env.json")]
    ['post']
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline, ProcessorStep
from lerobot.processor.pipeline import (
    ActionProcessorStep,
    ObservationProcessorStep,
    PolicyActionProcessorStep,
    ProcessorStepRegistry,
)
from lerobot.utils.constants import ACTION, OBS_STATE

from hub_envs._compat import processor_step_names
from hub_envs.envcode.importing import ROOT_PACKAGE, resolve_entry_point
from hub_envs.errors import HubEnvsError, ProcessorError
from hub_envs.harness.episode import SeededEpisode
from hub_envs.harness.policy import policy_observation
from hub_envs.loading.processor_specs import (  # noqa: F401  (re-exported: the declarations, parsed without torch)
    BUILTIN_NAMES,
    FIELDS,
    STAGES,
    ProcessorSpec,
    parse_declarations,
)
from hub_envs.loading.processor_specs import declarations_source as _source

# --- built-in steps ---------------------------------------------------------------------------


def _register(name: str):
    """Register with LeRobot's ProcessorStepRegistry (so saved pipelines name the step), once per process."""

    def deco(cls):
        if name not in processor_step_names():
            ProcessorStepRegistry.register(name)(cls)
        else:
            cls._registry_name = name
        return cls

    return deco


@_register("hub_envs/clip_action")
@dataclass
class ClipActionProcessorStep(ActionProcessorStep):
    """Clamp a ``(batch, action_dim)`` action tensor to ``[low, high]`` (per dimension or scalars).

    Built from a manifest without ``low``/``high``, the bounds are the env's ``action_space``.
    """

    low: list[float] | float | None = None
    high: list[float] | float | None = None

    @classmethod
    def from_spaces(cls, *, action_space=None, observation_space=None, **kwargs):
        """The step for an env: ``low``/``high`` not given are the bounds of its Box ``action_space``.

        Args:
            action_space: the env's action space.
            observation_space: the env's observation space (unused).
            kwargs: the declaration's ``kwargs`` (``low``, ``high``).

        Returns:
            The step.

        Raises:
            TypeError: no bounds given and no Box action space to take them from.
        """
        if ("low" not in kwargs or "high" not in kwargs) and action_space is not None:
            if not hasattr(action_space, "low"):
                raise TypeError(f"clip_action needs a Box action space or explicit low/high, got {action_space}")
            kwargs.setdefault("low", np.asarray(action_space.low, dtype=np.float64).tolist())
            kwargs.setdefault("high", np.asarray(action_space.high, dtype=np.float64).tolist())
        return cls(**kwargs)

    def __post_init__(self):
        if self.low is None or self.high is None:
            raise TypeError("clip_action needs low and high (or an env whose action_space gives them)")
        low, high = np.asarray(self.low, dtype=np.float64), np.asarray(self.high, dtype=np.float64)
        if low.shape != high.shape or np.any(low > high):
            raise ValueError(f"clip_action: low {self.low} and high {self.high} must have one shape and low <= high")

    def action(self, action):
        """Clamp an action.

        Args:
            action: a ``(batch, action_dim)`` tensor.

        Returns:
            It, clamped to ``[low, high]``.

        Raises:
            TypeError: not a tensor.
        """
        if not isinstance(action, torch.Tensor):
            raise TypeError(f"clip_action expects a torch.Tensor action, got {type(action).__name__}")
        low = torch.as_tensor(self.low, dtype=action.dtype, device=action.device)
        high = torch.as_tensor(self.high, dtype=action.dtype, device=action.device)
        return torch.maximum(torch.minimum(action, high), low)

    def get_config(self) -> dict[str, Any]:
        """The step's settings, as LeRobot saves them with a pipeline."""
        return {"low": self.low, "high": self.high}

    def transform_features(self, features):
        """Clamping changes no feature.

        Args:
            features: the pipeline's features.

        Returns:
            ``features``.
        """
        return features


def _flat(value, prefix: str) -> list[tuple[str, torch.Tensor]]:
    if isinstance(value, dict):
        out = []
        for k in sorted(value):
            out.extend(_flat(value[k], f"{prefix}/{k}"))
        return out
    return [(prefix, torch.as_tensor(value))]


@_register("hub_envs/flatten_state")
@dataclass
class FlattenStateProcessorStep(ObservationProcessorStep):
    """Concatenate observation entries (nested dicts flattened in sorted key order) into one state vector.

    ``keys`` are observation keys, optionally with ``/`` paths into nested dicts
    (``observation.robot_state/eef/pos``); each value is flattened to ``(batch, -1)`` float32, in the
    order given. The result goes to ``output`` (``observation.state``); the sources are removed
    unless ``keep``.
    """

    keys: list[str] = field(default_factory=list)
    output: str = OBS_STATE
    keep: bool = False

    def __post_init__(self):
        if not self.keys or not all(isinstance(k, str) and k for k in self.keys):
            raise TypeError("flatten_state needs keys = [...] (observation keys, '/' for nested entries)")

    @staticmethod
    def _get(observation: dict, key: str):
        top, *path = key.split("/")
        value = observation[top]
        for part in path:
            value = value[part]
        return value

    def observation(self, observation):
        """Flatten the keys into one state vector.

        Args:
            observation: a batched observation.

        Returns:
            It with the ``keys`` concatenated into ``output`` (the sources removed unless ``keep``).

        Raises:
            KeyError: a key the observation does not have.
        """
        parts = []
        for key in self.keys:
            try:
                value = self._get(observation, key)
            except (KeyError, TypeError):
                raise KeyError(f"flatten_state: the observation has no {key!r} (it has {sorted(observation)})") from None
            for _, tensor in _flat(value, key):
                tensor = tensor.float()
                if tensor.dim() <= 1:
                    tensor = tensor.reshape(1, -1)
                parts.append(tensor.reshape(tensor.shape[0], -1))
        out = dict(observation)
        if not self.keep:
            for key in {k.split("/")[0] for k in self.keys}:
                out.pop(key, None)
        out[self.output] = torch.cat(parts, dim=-1)
        return out

    def get_config(self) -> dict[str, Any]:
        """The step's settings, as LeRobot saves them with a pipeline."""
        return {"keys": list(self.keys), "output": self.output, "keep": self.keep}

    def transform_features(self, features):
        """The features after the step.

        Args:
            features: the pipeline's features.

        Returns:
            Them with ``output`` (a STATE of the summed sizes) in place of the flattened keys.
        """
        obs = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        tops = [k.split("/")[0] for k in self.keys]
        if all(k in obs and "/" not in k for k in self.keys):
            size = int(sum(np.prod(obs[k].shape) for k in self.keys))
            obs[self.output] = PolicyFeature(type=FeatureType.STATE, shape=(size,))
        if not self.keep:
            for k in tops:
                if k != self.output:
                    obs.pop(k, None)
        return {**features, PipelineFeatureType.OBSERVATION: obs}


BUILTINS: dict[str, type] = dict(zip(BUILTIN_NAMES, (ClipActionProcessorStep, FlattenStateProcessorStep), strict=True))


# --- building ---------------------------------------------------------------------------------


def _step_class(spec: ProcessorSpec, *, package: str | None, at: str):
    entry = spec.entry_point
    if ":" in entry:
        if package is None:
            raise ProcessorError(f"{at}.entry_point {entry!r} names env code, but no env code is loaded.")

        try:
            return resolve_entry_point(sys.modules[package], entry, where=f"{at}.entry_point")
        except HubEnvsError as e:
            raise ProcessorError(str(e)) from e
    if entry in BUILTINS:
        return BUILTINS[entry]
    if entry in processor_step_names():
        return ProcessorStepRegistry.get(entry)
    raise ProcessorError(
        f"{at}.entry_point {entry!r} is not a built-in ({', '.join(BUILTINS)}), a LeRobot processor step "
        f'(lerobot.processor.ProcessorStepRegistry) or "module:Class" in the env\'s code.'
    )


def build_step(
    spec: ProcessorSpec, *, package: str | None = None, spaces: dict | None = None, where: str = "hub_env.json"
) -> ProcessorStep:
    """Instantiate one declared step.

    Args:
        spec: the declaration.
        package: the package of the env's imported code (for ``"module:Class"`` entry points).
        spaces: the env's ``action_space`` / ``observation_space`` (for a step built ``from_spaces``).
        where: names the declarations' source in messages.

    Returns:
        The LeRobot ``ProcessorStep``.

    Raises:
        ProcessorError: an unknown entry point, a step of the other stage, or kwargs the step refuses.
    """
    at = f"{where} processors[{spec.index}]"
    cls = _step_class(spec, package=package, at=at)
    if not (isinstance(cls, type) and issubclass(cls, ProcessorStep)):
        raise ProcessorError(f"{at}.entry_point {spec.entry_point!r} is {cls!r}, not a lerobot.processor.ProcessorStep subclass.")
    if spec.stage == "post" and issubclass(cls, ObservationProcessorStep):
        raise ProcessorError(f'{at}.stage is "post" but {cls.__name__} processes observations; use stage = "pre".')
    if spec.stage == "pre" and issubclass(cls, (ActionProcessorStep, PolicyActionProcessorStep)):
        raise ProcessorError(f'{at}.stage is "pre" but {cls.__name__} processes actions; use stage = "post".')
    try:
        if hasattr(cls, "from_spaces"):
            return cls.from_spaces(**(spaces or {}), **spec.kwargs)
        return cls(**spec.kwargs)
    except (TypeError, ValueError) as e:
        raise ProcessorError(f"{at}.kwargs {spec.kwargs} do not fit {cls.__name__}: {e}") from e
    except Exception as e:
        raise ProcessorError(f"{at}: building {cls.__name__}({spec.kwargs}) raised {type(e).__name__}: {e}") from e


def build_pipelines(specs: list[ProcessorSpec], **kwargs) -> tuple[PolicyProcessorPipeline, PolicyProcessorPipeline]:
    """The declared steps, in declaration order, as LeRobot's two env pipelines.

    Args:
        specs: the declarations.
        kwargs: :func:`build_step`'s keywords.

    Returns:
        ``(env_preprocessor, env_postprocessor)``.

    Raises:
        ProcessorError: as :func:`build_step`.
    """
    pre = [build_step(s, **kwargs) for s in specs if s.stage == "pre"]
    post = [build_step(s, **kwargs) for s in specs if s.stage == "post"]
    return (
        PolicyProcessorPipeline(steps=pre, name="hub_envs_env_preprocessor"),
        PolicyProcessorPipeline(steps=post, name="hub_envs_env_postprocessor"),
    )


def _run_stage(specs: list[ProcessorSpec], pipeline: Any, transition: Any, stage: str, on: str, where: str) -> Any:
    """Run the steps of one stage on ``transition``; the first that raises is named by its declaration."""
    for spec, step in zip([s for s in specs if s.stage == stage], pipeline.steps, strict=False):
        try:
            transition = step(transition)
        except Exception as e:
            raise ProcessorError(
                f"{where} processors[{spec.index}] ({spec.name!r}, stage {stage}) failed on {on}: "
                f"{type(e).__name__}: {e}. Fix the step or its kwargs in [tool.hub-envs.processors] "
                f"and re-publish with push_env."
            ) from e
    return transition


def dry_run(
    specs: list[ProcessorSpec],
    pre: PolicyProcessorPipeline,
    post: PolicyProcessorPipeline,
    env,
    *,
    seed: int = 0,
    task: str | None = "",
    where: str = "hub_env.json",
) -> None:
    """Run every step once on a live observation and a sampled action.

    Args:
        specs: the declarations.
        pre, post: their pipelines (:func:`build_pipelines`).
        env: a live env (reset with ``seed``).
        seed: the reset seed.
        task: the config's task text.
        where: names the declarations' source in messages.

    Raises:
        ProcessorError: naming the step that failed.
    """
    episode = SeededEpisode(env, seed, where=where)
    _run_stage(specs, pre, pre.to_transition(policy_observation(episode.obs, task)), "pre", "a live observation", where)
    action = torch.as_tensor(np.asarray(episode.sample(), dtype=np.float32)).reshape(1, -1)
    _run_stage(specs, post, post.to_transition({ACTION: action}), "post", "a sampled action", where)


# --- with a loaded env ------------------------------------------------------------------------


def _package(loaded) -> str:
    if getattr(loaded, "isolation", None) is not None:  # the env's code is not imported here (see load_env)
        return f"{ROOT_PACKAGE}.{loaded.env_class.target.key}"
    return ".".join(loaded.env_class.__module__.split(".")[:2])


def specs_for(loaded) -> list[ProcessorSpec]:
    """The processors a loaded env declares.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        Its :class:`ProcessorSpec` s (:func:`parse_declarations`).

    Raises:
        ProcessorError: a malformed declaration.
    """
    return parse_declarations(list(loaded.manifest.processors), where=_source(loaded))


def pipelines_for(loaded, cfg=None) -> tuple[PolicyProcessorPipeline, PolicyProcessorPipeline]:
    """Fresh pipelines for a loaded env.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.
        cfg: a config instance (default: the published one).

    Returns:
        ``(env_preprocessor, env_postprocessor)``.

    Raises:
        ProcessorError: as :func:`build_step`.
    """
    specs = specs_for(loaded)
    spaces: dict = {}
    if specs:
        cfg = cfg if cfg is not None else loaded.config
        # isolated: the spaces come from a proxy (the env runs in its worker)
        env = loaded.env_class(**cfg.gym_kwargs) if getattr(loaded, "isolation", None) is None else loaded.make(cfg)
        try:
            spaces = {"action_space": env.action_space, "observation_space": env.observation_space}
        finally:
            env.close()
    return build_pipelines(specs, package=_package(loaded), spaces=spaces, where=_source(loaded))


def validate_for(loaded, *, dry: bool = True) -> list[ProcessorSpec]:
    """What load_env runs: parse, build, and run every declared step once.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.
        dry: also run every step once on a live observation and a sampled action.

    Returns:
        The declarations.

    Raises:
        ProcessorError: naming the malformed declaration or the failing step.
    """
    specs = specs_for(loaded)
    if not specs:
        return specs
    pre, post = pipelines_for(loaded)
    if dry:
        env = loaded.make()
        try:
            dry_run(
                specs,
                pre,
                post,
                env,
                seed=int(loaded.manifest.seeds.get("check", 0)),
                task=loaded.config.task if isinstance(loaded.config.task, str) else "",
                where=_source(loaded),
            )
        finally:
            env.close()
    return specs
