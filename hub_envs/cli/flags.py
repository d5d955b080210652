"""Command-line flags and how they reach the Python API: the flags every command that loads an env
shares (``hub-envs load``, ``reproduce``, ``evaluate``, ``compare``; ``diff``, which loads two, takes
:class:`CodeFlags`, the part without ``--repo_id``), and :func:`call_with_flags`, which passes a command's
flags to the function of the same parameters, so a new flag is one dataclass field, not one more line
in each command.

A light module (no lerobot, no torch): the CLI's ``--help`` imports it.

    >>> def load(repo_id, *, revision=None, isolation="none", trust_remote_code=False):
    ...     return repo_id, revision, isolation, trust_remote_code
    >>> flags = EnvFlags(repo_id="user/name", isolation="process")
    >>> call_with_flags(load, flags, flags.repo_id, trust_remote_code=True)
    ('user/name', None, 'process', True)
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, TypeVar

from hub_envs.errors import ConfigError
from hub_envs.loading.isolated import CodeRun

T = TypeVar("T")
_KEYWORD = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)


@dataclass
class CodeFlags:
    """The consent to run an env repo's code, and how it runs (``hub-envs diff`` loads two, so has no ``--repo_id``)."""

    trust_remote_code: bool = False
    isolation: str = "none"  # "process": the env's code runs in worker processes; "venv": in a venv built from its requirements
    sandbox: bool = False  # the workers in a sandbox (no network, read-only files, no secrets, limits)
    versions: str = "current"  # "publisher" (with --isolation=venv): the publisher's recorded package versions
    step_timeout: float | None = None  # seconds a call into an isolated env may take (sandbox default 60)


@dataclass
class EnvFlags(CodeFlags):
    """Which env (``--repo_id``, ``--revision``), the consent to run its code, and how it runs."""

    repo_id: str | None = None
    revision: str | None = None


def call_with_flags(fn: Callable[..., T], flags: Any, *args: Any, **overrides: Any) -> T:
    """``fn(*args, **kwargs)``: ``kwargs`` are the fields of the dataclass ``flags`` that ``fn`` takes as
    keyword parameters (and ``args`` do not bind already), then ``overrides`` (a flag's value converted,
    or a parameter that is no flag). Fields ``fn`` does not take (``--json``, ``--out`` of a printer) stay out.
    """
    params = inspect.signature(fn).parameters
    bound = set(list(params)[: len(args)])
    # ``**run: Unpack[CodeRun]`` takes CodeRun's keywords (another ``**kwargs`` takes no flag it does not name)
    takes_run = any(p.kind is inspect.Parameter.VAR_KEYWORD and "CodeRun" in str(p.annotation) for p in params.values())
    kwargs = {
        f.name: getattr(flags, f.name)
        for f in fields(flags)
        if (f.name in params and f.name not in bound and params[f.name].kind in _KEYWORD)
        or (takes_run and f.name in CodeRun.__annotations__)
    }
    kwargs.update(overrides)
    return fn(*args, **kwargs)


#: The flags that name a Hub repo (or a local folder) or one of its revisions, in hub-envs' commands and LeRobot's.
REPO_FLAGS = ("repo_id", "revision", "old", "new", "policy", "policies", "env.repo_id", "env.revision", "env.type")


def check_repo_flags(argv: list[str]) -> None:
    """Refuse a repo flag (:data:`REPO_FLAGS`) whose text holds a newline, a control character or surrounding spaces.

    draccus reads every flag's value as YAML, which drops a trailing newline or space without a word
    (``--repo_id=$'user/name\\n'`` became ``user/name``) and fails on a control character with a parser
    traceback; the raw text is checked first, by the rule of :func:`hub_envs.repo.hub_io.parse_repo_ref` when it
    has the shape of a repo reference.

    >>> check_repo_flags(["--repo_id=user/name@main", "--policies=random, ./ckpt", "--episodes=3"])
    >>> check_repo_flags(["--repo_id=user/name\\n"])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hub_envs.errors.ConfigError: --repo_id 'user/name\\n' is not valid: it holds a character that is not an ASCII letter, ...

    Raises:
        ConfigError: naming the flag, its value (``repr``) and the rule.
    """
    for i, arg in enumerate(argv):
        name, sep, value = arg.removeprefix("--").partition("=")
        if not arg.startswith("--") or name not in REPO_FLAGS:
            continue
        if not sep:  # --flag value
            if i + 1 >= len(argv):
                continue
            value = argv[i + 1]
        items = [v.strip(" ") for v in value.split(",")] if name == "policies" else [value]
        for item in items:
            if item.isprintable() and item == item.strip():
                continue
            if "/" in item and "revision" not in name:
                from hub_envs.repo import hub_io

                hub_io.parse_repo_ref(item, what=f"--{name}")
            raise ConfigError(
                f"--{name} {item!r} holds a newline, a control character or surrounding spaces: write it as it is "
                f"(a repo id 'user/name', a revision, or a path), nothing around it."
            )
