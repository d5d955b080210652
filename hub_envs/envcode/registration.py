"""Register a loaded env with gymnasium and its config with draccus, all or nothing (:func:`registry_transaction`), under
names hub-envs owns. A draccus choice whose config class is not imported yet waits until LeRobot's config system is
imported (by anyone): a load that needs neither LeRobot nor torch imports neither.

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
import importlib.util
import logging
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from hub_envs._compat import LEROBOT_ENV_PACKAGE, after_import, env_config_choices, lerobot_env_configs_imported
from hub_envs.envcode.importing import ROOT_PACKAGE
from hub_envs.errors import HubEnvsError, RegistrationConflictError

_log = logging.getLogger(__name__)

#: name -> owner key ("repo@sha") for every gym id and draccus choice hub-envs registered.
_OWNED_GYM: dict[str, str] = {}
_OWNED_CHOICES: dict[str, str] = {}
#: how many loads hold each registration: the same repo@sha loaded twice shares one, and it goes when the last goes
_HOLDS: dict[Registration, int] = {}
#: choice name -> the callable that imports its config class, for choices registered while LeRobot's config system was
#: not imported: :func:`_register_pending` registers them the moment it is (their owner is in ``_OWNED_CHOICES`` already)
_PENDING: dict[str, Callable[[], type]] = {}
#: the transactions open now (a choice registry that appears inside one is what it restores to)
_OPEN: list[Transaction] = []


@dataclass(frozen=True)
class Registration:
    """What one load registered: the gym id, the draccus choice name, and who owns them."""

    gym_id: str
    env_type: str
    owner: str


def _choices() -> dict[str, Any]:
    return env_config_choices()


def _loaded_choices() -> dict[str, Any] | None:
    """The live choice registry if LeRobot's config system is imported, else None (asking imports nothing)."""
    return env_config_choices() if lerobot_env_configs_imported() else None


def _register_pending(_module: Any = None) -> None:
    """Register the choices that waited for LeRobot's config system, now that it is imported (called inside the import
    statement that imported it, by :func:`hub_envs._compat.after_import`: it never raises). A choice whose config class
    cannot be imported or registered now is logged and left out: ``loaded.config_class`` raises its error."""
    choices = env_config_choices()
    for env_type, load_class in list(_PENDING.items()):
        owner = _OWNED_CHOICES.get(env_type)
        _PENDING.pop(env_type, None)
        try:
            _register_choice(env_type, owner, load_class())
        except Exception as e:  # noqa: BLE001 - the env's config code raised: never inside somebody else's import
            _OWNED_CHOICES.pop(env_type, None)
            what = str(e) if isinstance(e, HubEnvsError) else f"{type(e).__name__}: {e}"
            _log.warning("%s: its --env.type choice %r is not registered: %s", owner, env_type, what)
    for txn in _OPEN:  # LeRobot arrived inside the block: its own choices, and those of loads before it, stay
        if txn.choices_before is None:
            txn.choices_before = dict(choices)


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
    >>> from lerobot.envs.configs import EnvConfig
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
        choices = _loaded_choices()
        #: None while LeRobot's config system is not imported (:func:`_register_pending` fills it in when it is)
        self.choices_before: dict[str, Any] | None = dict(choices) if choices is not None else None
        if choices is None:
            after_import(LEROBOT_ENV_PACKAGE, _register_pending)

    def replaced(self) -> list[str]:
        """Names registered before the block whose entry something in the block replaced or removed
        (env code calling ``gym.register`` with a taken id overwrites it with only a warning)."""
        gym_now, choices_now = gym.registry, _loaded_choices() or {}
        out = [f"gym id {k!r}" for k, v in self.gym_before.items() if gym_now.get(k) is not v]
        out += [f"draccus choice {k!r}" for k, v in (self.choices_before or {}).items() if choices_now.get(k) is not v]
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
        gym_now, choices_now = gym.registry, _loaded_choices() or {}
        own: list[str] = []
        packages: dict[str, list[str]] = {}
        news = [(f"gym id {k!r}", gym_now.get(k), v) for k, v in self.gym_before.items()]
        news += [(f"draccus choice {k!r}", choices_now.get(k), v) for k, v in (self.choices_before or {}).items()]
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
    from importlib.metadata import packages_distributions  # heavy-ish (email, zipfile, csv): an entry was replaced

    distributions = packages_distributions().get(module.split(".")[0])
    return ", ".join(sorted(set(distributions))) if distributions else None


@contextlib.contextmanager
def registry_transaction():
    """On an exception inside the block, restore gymnasium's registry and draccus' EnvConfig choices."""
    txn = Transaction()
    gym_before = txn.gym_before
    owned_before = (dict(_OWNED_GYM), dict(_OWNED_CHOICES), dict(_HOLDS), dict(_PENDING))
    _OPEN.append(txn)
    try:
        yield txn
    except BaseException:
        gym.registry.clear()
        gym.registry.update(gym_before)
        choices = _loaded_choices()
        if choices is not None:  # None: LeRobot's config system is still not imported, so nothing was registered there
            choices.clear()
            choices.update(txn.choices_before or {})
        _PENDING.clear()
        _PENDING.update(owned_before[3])
        _OWNED_GYM.clear()
        _OWNED_GYM.update(owned_before[0])
        _OWNED_CHOICES.clear()
        _OWNED_CHOICES.update(owned_before[1])
        _HOLDS.clear()
        _HOLDS.update(owned_before[2])
        raise
    finally:
        _OPEN.remove(txn)


def snapshot_registries() -> tuple[dict, dict]:
    """A comparable picture of both registries (for tests and the reliability suite): name -> object id."""
    return {k: id(v) for k, v in gym.registry.items()}, {k: id(v) for k, v in _choices().items()}


def register(
    *,
    gym_id: str,
    env_type: str,
    owner: str,
    entry_point: Callable[..., gym.Env],
    config_class: type | Callable[[], type] | None,
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
        config_class: the EnvConfig subclass (None: no choice of its own), or a function without arguments that imports
            and returns it: then the choice is registered when LeRobot's config system is imported (at once if it is),
            so a process that never parses LeRobot configs never imports LeRobot for it.
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
    choices = _loaded_choices() if register_choice else None
    if register_choice and choices is not None and not isinstance(config_class, type) and callable(config_class):
        config_class = config_class()  # LeRobot's config system is here already: the class is cheap to import now
    if register_choice:  # an isolated env has no config class here to offer draccus: no choice, nothing to conflict
        taken = (choices or {}).get(env_type) is not None or env_type in _PENDING
        if taken and _OWNED_CHOICES.get(env_type) != owner:
            what = (choices or {}).get(env_type) or "a load waiting for LeRobot's config system"
            raise RegistrationConflictError(
                f"draccus choice {env_type!r} is already registered for {what!r}, not by {owner}. "
                f"Pick another name or load in a fresh process."
            )
    if register_choice and choices is not None:
        _check_choice_class(env_type, config_class, choices)
    if gym_id not in gym.registry:
        gym.register(
            id=gym_id,
            entry_point=entry_point,
            max_episode_steps=max_episode_steps,
            kwargs=dict(kwargs),
            disable_env_checker=disable_env_checker,
        )
        _OWNED_GYM[gym_id] = owner
    if register_choice and choices is not None and env_type not in choices:
        _register_choice(env_type, owner, config_class)
    elif register_choice and choices is None and env_type not in _PENDING and _OWNED_CHOICES.get(env_type) != owner:
        _PENDING[env_type] = (
            config_class if callable(config_class) and not isinstance(config_class, type) else lambda: config_class
        )
        _OWNED_CHOICES[env_type] = owner
        after_import(LEROBOT_ENV_PACKAGE, _register_pending)
    held = Registration(gym_id=gym_id, env_type=env_type, owner=owner)
    _HOLDS[held] = _HOLDS.get(held, 0) + 1
    return held


def _check_choice_class(env_type: str, config_class: Any, choices: dict[str, Any]) -> None:
    """Refuse a config class that cannot be the choice ``env_type`` (:class:`RegistrationConflictError`)."""
    from lerobot.envs.configs import EnvConfig  # heavy: lerobot (torch); its config system is imported already

    if not (isinstance(config_class, type) and issubclass(config_class, EnvConfig)):
        raise RegistrationConflictError(
            f"{config_class!r} is not a subclass of lerobot's EnvConfig; it cannot be a --env.type choice."
        )
    # A config class registered under another name by its own module would make `cfg.type` ambiguous.
    for name in [n for n, c in choices.items() if c is config_class and n != env_type]:
        if _OWNED_CHOICES.get(name) is None:
            raise RegistrationConflictError(
                f"{config_class.__qualname__} registered itself as the choice {name!r}. Remove its "
                f"@EnvConfig.register_subclass decorator: hub-envs registers it as {env_type!r}."
            )


def _register_choice(env_type: str, owner: str | None, config_class: Any) -> None:
    """Register ``config_class`` (with the consent field) as the choice ``env_type`` of LeRobot's ``EnvConfig``, owned by
    ``owner``."""
    from lerobot.envs.configs import EnvConfig  # heavy: lerobot (torch); its config system is imported already

    choices = env_config_choices()
    _check_choice_class(env_type, config_class, choices)
    if env_type not in choices:
        EnvConfig.register_subclass(env_type)(consenting_choice(config_class))
    _OWNED_CHOICES[env_type] = owner


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
        _PENDING.pop(registration.env_type, None)
        choices = _loaded_choices()
        if choices is not None:
            choices.pop(registration.env_type, None)
        del _OWNED_CHOICES[registration.env_type]


def owner_of_choice(env_type: str) -> str | None:
    """Who registered a draccus choice through hub-envs.

    Args:
        env_type: a choice name.

    Returns:
        The owner (``user/name@<sha>``), or None when hub-envs did not register it.
    """
    return _OWNED_CHOICES.get(env_type)
