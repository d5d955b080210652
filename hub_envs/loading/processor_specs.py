"""Env processor declarations (``[[tool.hub-envs.processors]]``, the manifest's ``processors``) parsed and validated as
pure data: no torch, no LeRobot (building and running the steps is :mod:`hub_envs.loading.processors`).

Example:
    >>> from hub_envs.loading.processor_specs import parse_declarations
    >>> [s.stage for s in parse_declarations([{"name": "clip_action", "stage": "post"}], where="hub_env.json")]
    ['post']
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from typing import Any

from hub_envs.errors import ProcessorError

STAGES = ("pre", "post")
FIELDS = ("name", "entry_point", "kwargs", "stage")
#: The built-in steps' names (:data:`hub_envs.loading.processors.BUILTINS` has their classes).
BUILTIN_NAMES = ("clip_action", "flatten_state")
_ENTRY_RE = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_][\w.]*$")


@dataclass(frozen=True)
class ProcessorSpec:
    """One validated declaration."""

    index: int
    name: str
    entry_point: str
    stage: str
    kwargs: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """The declaration as the manifest records it."""
        return {"name": self.name, "entry_point": self.entry_point, "stage": self.stage, "kwargs": dict(self.kwargs)}


def parse_declarations(declarations: Any, *, where: str) -> list[ProcessorSpec]:
    """Validate a ``processors`` list (pure data; nothing is imported).

    Args:
        declarations: the list of tables (``[[tool.hub-envs.processors]]``, or the manifest's ``processors``).
        where: names their source in messages.

    Returns:
        One :class:`ProcessorSpec` per declaration, in order.

    Raises:
        ProcessorError: naming the entry and field, e.g. ``hub_env.json processors[1].stage``.
    """
    if declarations is None:
        return []
    if not isinstance(declarations, (list, tuple)):
        raise ProcessorError(f"{where}: 'processors' must be a list of tables, got {type(declarations).__name__}.")
    specs: list[ProcessorSpec] = []
    seen: set[str] = set()
    for i, decl in enumerate(declarations):
        at = f"{where} processors[{i}]"
        if not isinstance(decl, dict):
            raise ProcessorError(
                f'{at} must be a table like {{name = "clip", entry_point = "clip_action", stage = "post"}}, got {decl!r}.'
            )
        unknown = sorted(set(decl) - set(FIELDS))
        if unknown:
            raise ProcessorError(f"{at}: unknown field(s) {unknown}; a processor has {list(FIELDS)}.")
        name = decl.get("name")
        if not isinstance(name, str) or not name.strip():
            raise ProcessorError(
                f'{at}.name is missing or not a non-empty string; give every processor a label, e.g. name = "clip".'
            )
        if name in seen:
            raise ProcessorError(f"{at}.name {name!r} is used twice; processor names must be unique.")
        seen.add(name)
        entry = decl.get("entry_point", name)
        if not isinstance(entry, str) or not entry:
            raise ProcessorError(
                f'{at}.entry_point must be a string: a built-in ({", ".join(BUILTIN_NAMES)}), a LeRobot processor name, or "module:Class".'
            )
        if ":" in entry and not _ENTRY_RE.match(entry):
            raise ProcessorError(f'{at}.entry_point {entry!r} is not of the form "module:Class".')
        if "stage" not in decl:
            raise ProcessorError(f'{at}.stage is missing: "pre" (observation -> policy) or "post" (policy action -> env).')
        stage = decl["stage"]
        if stage not in STAGES:
            raise ProcessorError(
                f'{at}.stage = {stage!r} must be "pre" (observation -> policy) or "post" (policy action -> env).'
            )
        kwargs = decl.get("kwargs", {})
        if not isinstance(kwargs, dict) or not all(isinstance(k, str) for k in kwargs):
            raise ProcessorError(f"{at}.kwargs must be a table of keyword arguments, got {kwargs!r}.")
        try:
            json.dumps(kwargs, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ProcessorError(f"{at}.kwargs must hold JSON values (numbers, strings, booleans, lists, tables): {e}.") from None
        specs.append(ProcessorSpec(index=i, name=name, entry_point=entry, stage=stage, kwargs=dict(kwargs)))
    return specs


def declarations_source(loaded) -> str:
    """Where a loaded env's declarations come from, as messages name it.

    Args:
        loaded: a :class:`~hub_envs.loading.loaded.LoadedEnv`.

    Returns:
        ``"<folder>/pyproject.toml [tool.hub-envs]"`` for a local folder, else ``"user/name@<sha>: hub_env.json"``.
    """
    if loaded.local_folder is not None and not (loaded.path / "hub_env.json").is_file():
        return f"{loaded.local_folder / 'pyproject.toml'} [tool.hub-envs]"
    return f"{loaded.repo_id}@{loaded.revision}: hub_env.json"
