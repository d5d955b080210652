"""A command line read before any parser or library: its flags checked against the command's (with "did you mean"),
its positional repo ids turned into flags, then draccus with a usage line that names the command.

Example:
    >>> suggest("revison", ["repo_id", "revision", "seed"])
    'revision'
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import draccus

from hub_envs._text import safe_text
from hub_envs.errors import ConfigError, UsageError
from hub_envs.repo.refs import check_repo_flags

#: what draccus accepts besides a config's fields: its config file, and help
DRACCUS_FLAGS = ("config_path", "help", "h")
#: the fields that consent to running a repo's code: given on the command line only, never by a ``--config_path`` file
#: (a config someone shared describes a run; it never carries consent: docs/security.md)
CONSENT_FIELDS = ("trust_remote_code", "trust_policy_code")


def parse_config(prog: str, config_class: type, argv: Sequence[str], *, positional: Sequence[str] = ()) -> Any:
    """Parse a command's arguments into its ``Config``: positional values to their flags, every flag checked, then draccus.

    Args:
        prog: the command, as usage lines and messages name it (``"hub-envs reproduce"``, ``"push_env"``).
        config_class: the command's ``Config`` dataclass.
        argv: its arguments.
        positional: the fields a bare value fills, in order (``("repo_id",)``; ``hub-envs diff``: ``("old", "new")``).

    Returns:
        An instance of ``config_class``.

    Raises:
        UsageError: a flag the command does not have, a positional value it does not take, or a value given both as a
            positional and as its flag, differently.
        ConfigError: a repo flag holding a newline, a control character or surrounding spaces
            (:func:`~hub_envs.repo.refs.check_repo_flags`), or consent given by a ``--config_path`` file
            (:func:`check_consent_from_command_line`).
        SystemExit: draccus' own answer (``--help``: 0; a value it cannot read: 2, argparse's usage and message).
    """
    argv = with_positional_as_flags(prog, argv, positional)
    check_repo_flags(argv)  # before draccus, which drops a trailing newline of a flag's value
    names = flag_names(config_class)
    check_flags(prog, argv, names)
    config = draccus.parse(config_class=config_class, args=argv, prog=prog)
    check_consent_from_command_line(prog, config, argv, names)
    return config


def check_consent_from_command_line(prog: str, config: Any, argv: Sequence[str], names: Sequence[str]) -> None:
    """Refuse consent (:data:`CONSENT_FIELDS`) that a ``--config_path`` file gave rather than the command line.

    Args:
        prog: the command, as the message names it.
        config: the parsed config.
        argv: the arguments it was parsed from (flags only).
        names: its flag names (:func:`flag_names`).

    Raises:
        ConfigError: naming the field, the file and the flag to pass instead.

    >>> from hub_envs.cli.audit import Config
    >>> check_consent_from_command_line(
    ...     "hub-envs audit", Config(trust_remote_code=True), ["--config_path=c.yaml"], ["trust_remote_code"]
    ... )  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hub_envs.errors.ConfigError: hub-envs audit: c.yaml sets trust_remote_code, which consents to running a repo's code: ...
    """
    given = dict(flags(argv))
    if "config_path" not in given:
        return
    for name in names:
        if name.rsplit(".", 1)[-1] not in CONSENT_FIELDS or name in given:
            continue
        value = config
        for part in name.split("."):
            value = getattr(value, part, None)
        if value:
            raise ConfigError(
                f"{prog}: {given['config_path']} sets {name}, which consents to running a repo's code: a config file "
                f"never carries consent. Pass --{name}=true on the command line (or trust the commit once: hub-envs trust "
                f"user/name@<sha>), and remove it from the file."
            )


def flag_names(config_class: type, prefix: str = "") -> list[str]:
    """Every flag draccus makes of a config dataclass: its fields, a nested dataclass's as ``outer.inner``.

    Args:
        config_class: a dataclass.
        prefix: the dotted path down to it.

    Returns:
        The flag names without ``--``, in field order.

    >>> from hub_envs.cli.serve import Config
    >>> flag_names(Config)[:3]
    ['root', 'host', 'port']
    """
    hints = typing.get_type_hints(config_class)
    names = []
    for field in dataclasses.fields(config_class):
        if not field.init:
            continue
        names.append(prefix + field.name)
        kind = hints.get(field.name)
        if isinstance(kind, type) and dataclasses.is_dataclass(kind):
            names += flag_names(kind, f"{prefix}{field.name}.")
    return names


def check_flags(command: str, argv: Sequence[str], known: Iterable[str], *, nested: bool = False) -> None:
    """Refuse every flag in ``argv`` that is not one of ``known`` (nor draccus' ``--config_path`` and ``--help``), naming
    the closest known one.

    Args:
        command: the command, as the message names it (``"hub-envs reproduce"``).
        argv: its arguments.
        known: its flag names, without ``--``.
        nested: only the first part of a dotted flag is checked (``--policy.x``: ``policy``): for LeRobot's configs,
            whose nested flags depend on a choice (``--policy.type``) only LeRobot's parser knows.

    Raises:
        UsageError: naming the command, each unknown flag and what was probably meant.

    >>> check_flags("hub-envs load", ["--repo_id=a/b", "--revison", "main"], ["repo_id", "revision"])
    Traceback (most recent call last):
    ...
    hub_envs.errors.UsageError: hub-envs load has no flag --revison: did you mean --revision? (hub-envs load --help lists its flags)
    """
    known = [*known, *DRACCUS_FLAGS]
    unknown = []
    for name, _value in flags(argv):
        checked = name.split(".")[0] if nested else name
        if checked not in known:
            unknown.append(name)
    if not unknown:
        return
    said = []
    for name in unknown:
        checked = name.split(".")[0] if nested else name
        close = suggest(checked, [k for k in known if k not in DRACCUS_FLAGS])
        rest = name[len(checked) :]
        said.append(f"--{safe_text(name)}" + (f": did you mean --{close}{safe_text(rest)}?" if close else ""))
    flag_word = "flag" if len(unknown) == 1 else "flags"
    raise UsageError(f"{command} has no {flag_word} {'; '.join(said)} ({command} --help lists its flags)")


def with_positional_as_flags(command: str, argv: Sequence[str], fields: Sequence[str]) -> list[str]:
    """``argv`` with each positional value turned into the flag it stands for (``user/name@<sha>`` ->
    ``--repo_id=user/name@<sha>``), put first; a value also given as its flag must be the same.

    Args:
        command: the command, as messages name it.
        argv: its arguments.
        fields: the fields positional values fill, in order.

    Returns:
        The arguments, flags only.

    Raises:
        UsageError: more positional values than ``fields``, or one given differently as its flag too.

    >>> with_positional_as_flags("hub-envs load", ["u/e@abc", "--check=false"], ["repo_id"])
    ['--repo_id=u/e@abc', '--check=false']
    >>> with_positional_as_flags("hub-envs load", ["u/e@abc", "--repo_id", "u/e@abc"], ["repo_id"])
    ['--repo_id', 'u/e@abc']
    """
    values = positionals(argv)
    if not values:
        return list(argv)
    if len(values) > len(fields):
        takes = (
            f"takes {len(fields)} positional value{'s' if len(fields) != 1 else ''} ({', '.join(fields)})"
            if fields
            else "takes no positional value"
        )
        extra = values[len(fields) :]
        raise UsageError(
            f"{command} {takes}; it was given {', '.join(repr(v) for v in extra)} too. "
            f"Pass values as --flag=value ({command} --help lists its flags)."
        )
    given = dict(flags(argv))
    out = []
    for field, value in zip(fields, values):
        if field in given and given[field] != value:
            raise UsageError(
                f"{command}: {field} was given twice, as {value!r} (positional) and as --{field}={safe_text(given[field])}; give it once."
            )
        if field not in given:
            out.append(f"--{field}={value}")
    return out + [arg for arg, role in _roles(argv) if role in ("flag", "value")]


def positionals(argv: Sequence[str]) -> list[str]:
    """The values in ``argv`` that are no flag and no flag's value (argparse's reading: ``--flag value`` takes the
    next argument unless it is a flag; ``--`` ends the flags).

    >>> positionals(["u/e@abc", "--seed", "3", "--json=true", "--", "-x"])
    ['u/e@abc', '-x']
    """
    return [arg for arg, role in _roles(argv) if role == "positional"]


def flags(argv: Sequence[str]) -> Iterator[tuple[str, str | None]]:
    """The flags in ``argv``: ``(name without dashes, its value or None)``, for ``--name=value``, ``--name value`` and
    a bare ``--name``/``-h``.

    >>> list(flags(["u/e", "--seed", "3", "--json=true", "-h"]))
    [('seed', '3'), ('json', 'true'), ('h', None)]
    """
    roles = list(_roles(argv))
    for i, (arg, role) in enumerate(roles):
        if role != "flag":
            continue
        name, sep, value = arg.lstrip("-").partition("=")
        if not sep:
            value = roles[i + 1][0] if i + 1 < len(roles) and roles[i + 1][1] == "value" else None
        yield name, value


def suggest(word: str, choices: Iterable[str]) -> str | None:
    """The choice closest to ``word`` (difflib's ratio, as CPython's own "did you mean"), or None when none is close.

    Args:
        word: what was typed.
        choices: what it could have meant.

    Returns:
        The closest choice, or None.

    >>> suggest("reprodcue", ["reproduce", "load", "diff"]), suggest("repo-id", ["repo_id"]), suggest("zzz", ["load"])
    ('reproduce', 'repo_id', None)
    """
    choices = list(choices)
    normal = word.replace("-", "_")
    if normal in choices:  # --repo-id: the same flag written with a dash
        return normal
    close = difflib.get_close_matches(normal, choices, n=1, cutoff=0.6)
    return close[0] if close else None


def _roles(argv: Sequence[str]) -> Iterator[tuple[str, str]]:
    """Each argument with its role: ``"flag"``, ``"value"`` (of the flag before it) or ``"positional"``."""
    after_dashes = False
    wants_value = False
    for arg in argv:
        if after_dashes:
            yield arg, "positional"
        elif arg == "--":
            after_dashes = True
            wants_value = False
            yield arg, "separator"
        elif _is_flag(arg):
            name, sep, _ = arg.partition("=")
            wants_value = arg.startswith("--") and not sep and name not in ("--help",)
            yield arg, "flag"
        elif wants_value:
            wants_value = False
            yield arg, "value"
        else:
            yield arg, "positional"


def _is_flag(arg: str) -> bool:
    """``-x``/``--x``, but not ``-1`` or ``-0.5`` (argparse reads a negative number as a value)."""
    if not arg.startswith("-") or arg == "-":
        return False
    try:
        float(arg)
    except ValueError:
        return True
    return False
