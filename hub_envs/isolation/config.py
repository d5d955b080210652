"""An isolated env's config (:class:`ManifestConfig`): the values push_env recorded in the verified manifest,
since the parent never imports the env's code. A local folder is your own code: its config class is imported.

Example:
    >>> from hub_envs.isolation.config import ManifestConfig
    >>> cfg = ManifestConfig({"episode_length": 30, "gym_kwargs": {"render_mode": "rgb_array"},
    ...                       "features": {"agent_pos": {"type": "STATE", "shape": [2]}}, "features_map": {}})
    >>> cfg.episode_length, cfg.gym_kwargs, cfg.features["agent_pos"].shape
    (30, {'render_mode': 'rgb_array'}, (2,))
"""

from __future__ import annotations

import copy
from typing import Any

from hub_envs.errors import ManifestError


class ManifestConfig:
    """The manifest's config values as read-only attributes: what hub-envs uses of a config (``episode_length``,
    ``gym_kwargs``, ``features`` as LeRobot ``PolicyFeature`` objects, ``features_map``, ``fps``, ``task``, ...).

    Args:
        values: ``hub_env.json``'s ``config``: every field of the repo's ``EnvConfig`` and its ``gym_kwargs``.
        where: what to name in an error (the manifest's path or repo@sha).

    Raises:
        ManifestError: the values lack ``episode_length`` or ``gym_kwargs`` (a manifest older than isolation).
    """

    def __init__(self, values: dict[str, Any], *, where: str = "hub_env.json"):
        if "episode_length" not in values or not isinstance(values.get("gym_kwargs"), dict):
            raise ManifestError(
                f"{where}: the manifest's config has no episode_length or gym_kwargs, which an isolated env needs (the "
                f"parent does not import the env's code). Re-publish with push_env."
            )
        self._values = copy.deepcopy(values)
        self._features = None

    @property
    def features(self) -> dict:
        if self._features is None:
            from lerobot.configs.types import FeatureType, PolicyFeature

            self._features = {
                k: PolicyFeature(type=FeatureType[v["type"]], shape=tuple(v["shape"]))
                for k, v in (self._values.get("features") or {}).items()
            }
        return self._features

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        return copy.deepcopy(self._values["gym_kwargs"])

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return copy.deepcopy(self._values[name])
        except KeyError:
            raise AttributeError(f"the manifest's config has no field {name!r}") from None

    def to_dict(self) -> dict[str, Any]:
        return copy.deepcopy(self._values)

    def __repr__(self) -> str:
        return (
            f"ManifestConfig({', '.join(f'{k}={v!r}' for k, v in self._values.items() if k not in ('features', 'features_map'))})"
        )
