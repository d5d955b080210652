"""Repo references: what names a Hub repo (``user/name@revision``) and what names a local folder, by one rule for
every entry that takes either, and the raw text of the flags that name one, checked before any parser reads it.

Example:
    >>> from hub_envs.repo.refs import parse_repo_ref
    >>> parse_repo_ref("user/pendulum-lerobot@v1")
    ('user/pendulum-lerobot', 'v1')
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

from hub_envs._text import safe_text
from hub_envs.errors import ConfigError
from hub_envs.repo.format import REPO_ID_RULE, repo_id_problem


def check_repo_id(repo_id: object, *, what: str = "Repo id") -> str:
    """``repo_id`` if it is a Hub repo id (``user/name``), else a :class:`~hub_envs.errors.ConfigError` naming the
    value (its ``repr``: a trailing newline shows) and the rule (:func:`hub_envs.repo.format.repo_id_problem`).

    Args:
        repo_id: the value given.
        what: how the message names it (``"--repo_id"``, ``"Repo id"``...).

    Returns:
        ``repo_id``, unchanged.

    Raises:
        ConfigError: ``repo_id`` is not a repo id.
    """
    problem = repo_id_problem(repo_id)
    if problem is not None:
        raise ConfigError(f"{what} {repo_id!r} is not valid: {problem}; {REPO_ID_RULE}.")  # repr: escapes shown
    return repo_id  # type: ignore[return-value]


def parse_repo_ref(ref: str, *, what: str = "Repo id") -> tuple[str, str | None]:
    """Split a repo reference: ``"user/name@rev"`` -> ``("user/name", "rev")``, ``"user/name"`` -> ``("user/name", None)``.

    Never a path: ``./x``, ``/abs``, ``~/x`` and anything with characters a Hub repo id cannot have (a trailing newline
    included) are refused.

    Args:
        ref: the reference.
        what: how messages name the value (``"--repo_id"``, ``"Repo id"``...).

    Returns:
        ``(repo_id, revision or None)``.

    Raises:
        ConfigError: not a repo id (:func:`check_repo_id`), a trailing ``@``, or an unprintable revision.
    """
    if not isinstance(ref, str) or not ref:
        raise ConfigError(f"{what} {ref!r} is not valid: use 'user/name', optionally '@revision'.")
    repo_id, _, revision = ref.partition("@")
    check_repo_id(repo_id, what=what)
    if "@" in ref and not revision:
        raise ConfigError(f"{ref!r} ends with '@' but names no revision. Write 'user/name@<sha, tag or branch>'.")
    if revision and not revision.isprintable():
        raise ConfigError(f"{what} {ref!r} is not valid: its revision holds characters that are not printable.")
    return repo_id, revision or None


#: Text that looks like a path (what ``local_path`` takes for a local folder whether or not it exists).
_PATH_PREFIXES = ("./", "../", "/", "~", ".\\")
#: What could name a Hub repo (``parse_repo_ref`` checks it): ``user/name``, optionally ``@revision``.
_REPO_REF_SHAPE = re.compile(r"[^/@]+/[^/@]+(@.*)?", re.S)


def local_path(ref: str | os.PathLike, *, stacklevel: int = 2) -> Path | None:
    """The local folder ``ref`` names, or None when it names a Hub repo: the one rule of every entry that takes
    either (``load_env`` and the commands' ``--repo_id``, ``compare``'s ``--policies``...).

    A local folder's code runs without consent, so it must never be picked by accident:

    * a ``Path`` (any ``os.PathLike``), or text that looks like a path (``./x``, ``../x``, ``/abs``, ``~/x``), is
      local, whether or not it exists (the caller says so when it does not);
    * ``user/name`` (optionally ``@revision``) always means the Hub, even when a folder of that name exists here
      (a warning then says to write ``./user/name`` for the folder; a :class:`~hub_envs.errors.ConfigError` if the
      text is no valid repo id);
    * other text (a bare ``name``, ``outputs/train/x``: no Hub repo id has that shape) is local when such a folder
      exists, else the caller's Hub parsing refuses it.

    Args:
        ref: what the caller was given.
        stacklevel: of the warning, as for :func:`warnings.warn` (counted from the caller of this function).

    Returns:
        The path (``~`` expanded), or None: a Hub repo reference.
    """
    if isinstance(ref, os.PathLike):
        return Path(ref).expanduser()
    if not isinstance(ref, str):
        return None
    path = Path(ref).expanduser()
    if ref.startswith(_PATH_PREFIXES):
        return path
    if _REPO_REF_SHAPE.fullmatch(ref):
        problem = repo_id_problem(ref.partition("@")[0])
        if path.is_dir() and problem is not None:
            raise ConfigError(
                f"{ref!r} is not a Hub repo id ({problem}), and a folder of that name exists here: "
                f"write './{safe_text(ref)}' to use the folder (a local folder is written as a path)."
            )
        if path.is_dir():
            warnings.warn(
                f"{ref!r} is taken from the Hub; a local folder of that name exists too: pass "
                f"'./{safe_text(ref)}' to use the folder instead.",
                stacklevel=stacklevel + 1,
            )
        return None
    return path if path.is_dir() else None


#: The flags that name a Hub repo (or a local folder) or one of its revisions, in hub-envs' commands and LeRobot's.
REPO_FLAGS = ("repo_id", "revision", "old", "new", "policy", "policies", "env.repo_id", "env.revision", "env.type", "from_repo")


def check_repo_flags(argv: list[str]) -> None:
    """Refuse a repo flag (:data:`REPO_FLAGS`) whose text holds a newline, a control character or surrounding spaces.

    draccus reads every flag's value as YAML, which drops a trailing newline or space without a word
    (``--repo_id=$'user/name\\n'`` became ``user/name``) and fails on a control character with a parser
    traceback; the raw text is checked first, by the rule of :func:`parse_repo_ref` when it
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
                parse_repo_ref(item, what=f"--{name}")
            raise ConfigError(
                f"--{name} {item!r} holds a newline, a control character or surrounding spaces: write it as it is "
                f"(a repo id 'user/name', a revision, or a path), nothing around it."
            )
