"""Register a loaded env with gymnasium and its config with draccus, all or nothing (:func:`registry_transaction`), under
names hub-envs owns.

Example:
    >>> import gymnasium as gym
    >>> from hub_envs.envcode.registration import registry_transaction
    >>> before = set(gym.registry)
    >>> with registry_transaction():
    ...     pass
    >>> set(gym.registry) == before
    True
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.metadata
import importlib.util
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from lerobot.envs.configs import EnvConfig

from hub_envs._compat import env_config_choices
from hub_envs.envcode.importing import ROOT_PACKAGE
from hub_envs.errors import RegistrationConflictError

#: name -> owner key ("repo@sha") for every gym id and draccus choice hub-envs registered.
_OWNED_GYM: dict[str, str] = {}
_OWNED_CHOICES: dict[str, str] = {}
#: how many loads hold each registration: the same repo@sha loaded twice shares one, and it goes when the last goes
_HOLDS: dict[Registration, int] = {}


@dataclass(frozen=True)
class Registration:
    """What one load registered: the gym id, the draccus choice name, and who owns them."""

    gym_id: str
    env_type: str
    owner: str


def _choices() -> dict[str, Any]:
    return env_config_choices()


#: The consent flag of LeRobot's CLIs for a hub env, ``--env.trust_remote_code=true``: a field of the ``hub`` choice,
#: and of every per-repo choice (:func:`consenting_choice`), so one spelling works with both.
CONSENT_FIELD = "trust_remote_code"
#: Fields a per-repo choice has for the command line only: :func:`hub_envs.envcode.envconfig.encode_config` leaves them out.
CLI_ONLY_FIELDS = "_hub_envs_cli_only"
_CONSENTING: dict[type, type] = {}


def consenting_choice(config_class: type) -> type:
    """The class a per-repo choice (``--env.type=user/name@<sha12>``) is registered as: ``config_class`` plus a
    ``trust_remote_code`` field, so LeRobot's parser accepts ``--env.trust_remote_code=true`` there as it does after
    ``--env.type=hub`` (else draccus refuses it: "The fields trust_remote_code are not valid for ..."). The consent
    itself is read from the command line before LeRobot parses it (:func:`hub_envs.lerobot.bridge.prepare_argv`):
    the field holds none, it is False once the config is built, so a saved ``train_config.json`` never carries consent.
    A class that is not a dataclass, or has that field already, is registered as it is.

    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class DemoConfig(EnvConfig):
    ...     @property
    ...     def gym_kwargs(self): return {}
    >>> cfg = consenting_choice(DemoConfig)(trust_remote_code=True)
    >>> isinstance(cfg, DemoConfig), cfg.trust_remote_code
    (True, False)
    """
    if not dataclasses.is_dataclass(config_class) or CONSENT_FIELD in {f.name for f in dataclasses.fields(config_class)}:
        return config_class
    if config_class not in _CONSENTING:

        def __post_init__(self) -> None:
            own = getattr(config_class, "__post_init__", None)
            if own is not None:
                own(self)
            object.__setattr__(self, CONSENT_FIELD, False)  # consent is given on a command line, never held by a config

        _CONSENTING[config_class] = dataclasses.make_dataclass(
            config_class.__name__,
            [(CONSENT_FIELD, bool, dataclasses.field(default=False))],
            bases=(config_class,),
            namespace={
                "__post_init__": __post_init__,
                "__module__": config_class.__module__,
                "__qualname__": config_class.__qualname__,
                "__doc__": config_class.__doc__,
                CLI_ONLY_FIELDS: (CONSENT_FIELD,),
            },
        )
        _CONSENTING[config_class].__module__ = config_class.__module__  # make_dataclass names the caller's module (3.12+)
    return _CONSENTING[config_class]


class Transaction:
    """What :func:`registry_transaction` yields: the registries as they were when it started."""

    def __init__(self) -> None:
        self.gym_before = dict(gym.registry)
        self.choices_before = dict(_choices())

    def replaced(self) -> list[str]:
        """Names registered before the block whose entry something in the block replaced or removed
        (env code calling ``gym.register`` with a taken id overwrites it with only a warning)."""
        gym_now, choices_now = gym.registry, _choices()
        out = [f"gym id {k!r}" for k, v in self.gym_before.items() if gym_now.get(k) is not v]
        out += [f"draccus choice {k!r}" for k, v in self.choices_before.items() if choices_now.get(k) is not v]
        return out

    def replaced_by(self, code: str | os.PathLike) -> tuple[list[str], dict[str, list[str]]]:
        """What replaced an entry during the transaction, and whose doing it was. A new entry belongs to whatever holds what
        it points at (its entry point, its config class): the env's code (the folder ``code``, or any module hub-envs
        imported from a repo), or the package of an installed distribution (gymnasium-robotics re-registers gymnasium's
        MuJoCo ids when it is imported). Anything that cannot be placed (removed, or pointing at no importable module)
        counts as the env's.

        Args:
            code: the folder the env's code was imported from.

        Returns:
            ``(names the env's own code took over, {installed distribution: names its package took over})``.
        """
        gym_now, choices_now = gym.registry, _choices()
        own: list[str] = []
        packages: dict[str, list[str]] = {}
        news = [(f"gym id {k!r}", gym_now.get(k), v) for k, v in self.gym_before.items()]
        news += [(f"draccus choice {k!r}", choices_now.get(k), v) for k, v in self.choices_before.items()]
        for name, now, before in news:
            if now is before:
                continue
            target = getattr(now, "entry_point", now)  # a gym EnvSpec points at its entry point; a choice is a class
            distribution = _installed_origin(target, Path(code)) if now is not None else None
            if distribution is None:
                own.append(name)
            else:
                packages.setdefault(distribution, []).append(name)
        return own, packages


def _installed_origin(target: Any, code: Path) -> str | None:
    """The installed distribution(s) whose package holds ``target`` (a ``"module:attr"`` entry point, a callable or a
    class), e.g. ``"gymnasium-robotics"``; None for the env's own code (``code``, or a module of a hub-envs repo)
    and for what cannot be placed."""
    module = target.split(":", 1)[0] if isinstance(target, str) else getattr(target, "__module__", None)
    if not isinstance(module, str) or not module or module.split(".")[0] == ROOT_PACKAGE:
        return None
    file = getattr(sys.modules.get(module), "__file__", None)
    if file is None:
        try:  # a string entry point of a module not imported yet (its package is: it registered the id)
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            return None
        file = spec.origin if spec is not None else None
    if not file or Path(file).resolve().is_relative_to(code.resolve()):
        return None
    distributions = importlib.metadata.packages_distributions().get(module.split(".")[0])
    return ", ".join(sorted(set(distributions))) if distributions else None


@contextlib.contextmanager
def registry_transaction():
    """On an exception inside the block, restore gymnasium's registry and draccus' EnvConfig choices."""
    txn = Transaction()
    gym_before, choices_before = txn.gym_before, txn.choices_before
    owned_before = (dict(_OWNED_GYM), dict(_OWNED_CHOICES), dict(_HOLDS))
    try:
        yield txn
    except BaseException:
        gym.registry.clear()
        gym.registry.update(gym_before)
        _choices().clear()
        _choices().update(choices_before)
        _OWNED_GYM.clear()
        _OWNED_GYM.update(owned_before[0])
        _OWNED_CHOICES.clear()
        _OWNED_CHOICES.update(owned_before[1])
        _HOLDS.clear()
        _HOLDS.update(owned_before[2])
        raise


def snapshot_registries() -> tuple[dict, dict]:
    """A comparable picture of both registries (for tests and the reliability suite): name -> object id."""
    return {k: id(v) for k, v in gym.registry.items()}, {k: id(v) for k, v in _choices().items()}


def register(
    *,
    gym_id: str,
    env_type: str,
    owner: str,
    entry_point: Callable[..., gym.Env],
    config_class: type,
    max_episode_steps: int | None,
    kwargs: dict[str, Any],
    disable_env_checker: bool = True,
    register_choice: bool = True,
) -> Registration:
    """Register ``gym_id`` with gymnasium and ``env_type`` as an EnvConfig choice, idempotent per owner: each call is one more
    hold on the same :class:`Registration`, released by :func:`unregister`.

    Args:
        gym_id: the gym id.
        env_type: the draccus choice name.
        owner: who registers it (``user/name@<sha>``, with an isolated load's mode).
        entry_point: the env class (or an isolated load's factory of proxies).
        config_class: the EnvConfig subclass (None: no choice of its own).
        max_episode_steps: the time limit.
        kwargs: the env's keyword arguments (``gym_kwargs``).
        disable_env_checker: gymnasium's env checker off (hub-envs runs its own checks).
        register_choice: also register the draccus choice.

    Returns:
        The :class:`Registration`.

    Raises:
        RegistrationConflictError: a name held by anything else (never overwritten).
    """
    if gym_id in gym.registry and _OWNED_GYM.get(gym_id) == owner and gym.registry[gym_id].entry_point is not entry_point:
        _OWNED_GYM.pop(gym_id)  # replaced behind our back: it is no longer ours
    if gym_id in gym.registry and _OWNED_GYM.get(gym_id) != owner:
        holder = _OWNED_GYM.get(gym_id) or gym.registry[gym_id].entry_point
        raise RegistrationConflictError(
            f"gym id {gym_id!r} is already registered by {holder!r}, not by {owner}. "
            f"Unregister it first (hub_envs.unregister / del gymnasium.registry[{gym_id!r}]) or load in a fresh process."
        )
    existing = _choices().get(env_type)
    if not register_choice:  # an isolated env: the parent has no config class to offer draccus
        existing = None
    if existing is not None and _OWNED_CHOICES.get(env_type) != owner:
        raise RegistrationConflictError(
            f"draccus choice {env_type!r} is already registered for {existing!r}, not by {owner}. "
            f"Pick another name or load in a fresh process."
        )
    if register_choice and not (isinstance(config_class, type) and issubclass(config_class, EnvConfig)):
        raise RegistrationConflictError(
            f"{config_class!r} is not a subclass of lerobot's EnvConfig; it cannot be a --env.type choice."
        )
    # A config class registered under another name by its own module would make `cfg.type` ambiguous.
    other_names = [n for n, c in _choices().items() if c is config_class and n != env_type] if register_choice else []
    for name in other_names:
        if _OWNED_CHOICES.get(name) is None:
            raise RegistrationConflictError(
                f"{config_class.__qualname__} registered itself as the choice {name!r}. Remove its "
                f"@EnvConfig.register_subclass decorator: hub-envs registers it as {env_type!r}."
            )
    if gym_id not in gym.registry:
        gym.register(
            id=gym_id,
            entry_point=entry_point,
            max_episode_steps=max_episode_steps,
            kwargs=dict(kwargs),
            disable_env_checker=disable_env_checker,
        )
        _OWNED_GYM[gym_id] = owner
    if register_choice and env_type not in _choices():
        EnvConfig.register_subclass(env_type)(consenting_choice(config_class))
        _OWNED_CHOICES[env_type] = owner
    held = Registration(gym_id=gym_id, env_type=env_type, owner=owner)
    _HOLDS[held] = _HOLDS.get(held, 0) + 1
    return held


def unregister(registration: Registration) -> None:
    """Release one hold on what :func:`register` added; the last one removes it (only if hub-envs still owns it).

    Args:
        registration: what :func:`register` returned.
    """
    holds = _HOLDS.pop(registration, 0) - 1
    if holds > 0:  # another load of the same repo@sha still uses it
        _HOLDS[registration] = holds
        return
    if _OWNED_GYM.get(registration.gym_id) == registration.owner:
        gym.registry.pop(registration.gym_id, None)
        del _OWNED_GYM[registration.gym_id]
    if _OWNED_CHOICES.get(registration.env_type) == registration.owner:
        _choices().pop(registration.env_type, None)
        del _OWNED_CHOICES[registration.env_type]


def owner_of_choice(env_type: str) -> str | None:
    """Who registered a draccus choice through hub-envs.

    Args:
        env_type: a choice name.

    Returns:
        The owner (``user/name@<sha>``), or None when hub-envs did not register it.
    """
    return _OWNED_CHOICES.get(env_type)
