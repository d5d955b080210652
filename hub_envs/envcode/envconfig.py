"""What hub-envs expects of an env's LeRobot ``EnvConfig`` subclass, and its serialized values.

An env's config is a ``@dataclass`` subclass of ``lerobot.envs.configs.EnvConfig`` (not registered
by its own module: hub-envs registers it) with an ``episode_length`` field and a ``gym_kwargs``
property giving the env constructor's keyword arguments.

Example:
    >>> from lerobot.envs.configs import PushtEnv
    >>> from hub_envs.envcode.envconfig import encode_config
    >>> encode_config(PushtEnv())["features"]["agent_pos"] == {"type": "STATE", "shape": [2]}
    True
"""

from __future__ import annotations

import dataclasses
import json
import typing
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from hub_envs.envcode.registration import CLI_ONLY_FIELDS
from hub_envs.errors import ConfigError, EnvCodeError, InvalidRepoFormatError

if TYPE_CHECKING:  # pragma: no cover
    from lerobot.envs.configs import EnvConfig


def validate_config_class(config_class: Any, *, where: str) -> None:
    """Refuse a config entry point that is not a ``@dataclass`` subclass of LeRobot's ``EnvConfig`` with an
    ``episode_length`` field and a ``gym_kwargs`` property.

    Args:
        config_class: what the entry point named.
        where: names the repo in messages.

    Raises:
        InvalidRepoFormatError: saying what the class lacks.
    """
    from lerobot.envs.configs import EnvConfig  # heavy: lerobot (torch); the class's own module imported it already

    if not (isinstance(config_class, type) and issubclass(config_class, EnvConfig)):
        raise InvalidRepoFormatError(
            f"{where}: the config entry point is {config_class!r}, not a subclass of lerobot.envs.configs.EnvConfig. "
            f"Point [tool.hub-envs] config at a @dataclass subclass of EnvConfig."
        )
    if not dataclasses.is_dataclass(config_class):
        raise InvalidRepoFormatError(f"{where}: {config_class.__qualname__} is not a @dataclass. Decorate it with @dataclass.")
    names = {f.name for f in dataclasses.fields(config_class)}
    if "episode_length" not in names:
        raise InvalidRepoFormatError(
            f"{where}: {config_class.__qualname__} has no 'episode_length' field. Add `episode_length: int = 200` "
            f"(hub-envs uses it as max_episode_steps)."
        )


def instantiate_config(config_class: type, *, where: str, overrides: Mapping[str, Any] | None = None) -> EnvConfig:
    """Build the config: its defaults, with ``overrides`` (field values, decoded by draccus as LeRobot's
    ``--env.<field>=<value>`` flags are: ``{"episode_length": "50"}`` gives the int 50) set before its
    ``__post_init__`` runs, so what it computes follows them.

    >>> from dataclasses import dataclass
    >>> from lerobot.envs.configs import EnvConfig
    >>> @dataclass
    ... class DemoConfig(EnvConfig):
    ...     episode_length: int = 200
    ...     @property
    ...     def gym_kwargs(self): return {}
    >>> instantiate_config(DemoConfig, where="demo", overrides={"episode_length": "50"}).episode_length
    50
    """
    import draccus  # heavy: draccus (yaml); the class's module imported LeRobot, which imports it

    overrides = dict(overrides or {})
    names = {f.name for f in dataclasses.fields(config_class) if f.init}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ConfigError(f"{where}: {config_class.__qualname__} has no field(s) {unknown} to set. Its fields: {sorted(names)}.")
    try:
        # field by field (each value decoded to its field's type), then the constructor: decoding the whole class
        # would make draccus < 0.11 dispatch on a "type" key, EnvConfig being a choice registry
        hints = typing.get_type_hints(config_class)
        values = {name: draccus.decode(hints[name], value) for name, value in overrides.items()}
    except (TypeError, ValueError, NameError, draccus.ParsingError) as e:  # ParsingError: draccus' DecodingError too
        raise ConfigError(f"{where}: {config_class.__qualname__} with {overrides} is invalid: {e}") from e
    try:
        cfg = config_class(**values)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {config_class.__qualname__} with {overrides} is invalid: {e}") from e
    except Exception as e:
        raise EnvCodeError(f"{where}: {config_class.__qualname__}({overrides or ''}) raised {type(e).__name__}: {e}") from e
    try:
        gym_kwargs = cfg.gym_kwargs
    except Exception as e:
        raise EnvCodeError(f"{where}: {config_class.__qualname__}.gym_kwargs raised {type(e).__name__}: {e}") from e
    if not isinstance(gym_kwargs, dict):
        raise InvalidRepoFormatError(
            f"{where}: {config_class.__qualname__}.gym_kwargs must return a dict, got {type(gym_kwargs).__name__}."
        )
    if "max_episode_steps" in gym_kwargs:
        raise InvalidRepoFormatError(
            f"{where}: {config_class.__qualname__}.gym_kwargs contains 'max_episode_steps'; hub-envs sets it from "
            f"episode_length. Remove it from gym_kwargs."
        )
    return cfg


def encode_config(cfg: EnvConfig) -> dict[str, Any]:
    """The config's field values as JSON-ready data (draccus encoding), plus its ``gym_kwargs``.

    Args:
        cfg: an EnvConfig instance, or an isolated load's :class:`~hub_envs.isolation.config.ManifestConfig` (those values
            already).

    Returns:
        ``{field: value, ..., "gym_kwargs": {...}}``, round-tripped through JSON so it compares equal to a manifest's.
    """
    if not dataclasses.is_dataclass(cfg) and callable(getattr(cfg, "to_dict", None)):
        return json.loads(json.dumps(cfg.to_dict(), sort_keys=True))
    import draccus  # heavy: draccus (yaml); a dataclass config is LeRobot's, which imports it

    cli_only = getattr(type(cfg), CLI_ONLY_FIELDS, ())  # a per-repo choice's consent flag (registration.consenting_choice)
    out = {f.name: draccus.encode(getattr(cfg, f.name)) for f in dataclasses.fields(cfg) if f.name not in cli_only}
    out["gym_kwargs"] = draccus.encode(cfg.gym_kwargs)
    # round-trip through JSON so tuples/lists compare equal to what a manifest holds
    return json.loads(json.dumps(out, sort_keys=True))


def config_differences(recorded: dict[str, Any], actual: dict[str, Any]) -> list[str]:
    """The fields whose recorded and actual values differ.

    Args:
        recorded: the manifest's ``config``.
        actual: :func:`encode_config` of the config the code computes.

    Returns:
        One line per field: ``field: manifest X vs code Y``.
    """
    keys = sorted(set(recorded) | set(actual))
    return [
        f"{k}: manifest {recorded.get(k, '<absent>')!r} vs code {actual.get(k, '<absent>')!r}"
        for k in keys
        if recorded.get(k) != actual.get(k)
    ]
