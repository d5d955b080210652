"""An env of a plain LeRobot EnvHub repo (no hub_env.json), written by hub-envs. Do not edit: it is regenerated.

The repo's own files are in ``source/``, unchanged; its entry file's ``make_env(n_envs, use_async_envs, cfg=None)``
builds the env (LeRobot's EnvHub contract), called with ``n_envs=1, use_async_envs=False``: the one env it returns
(a ``gym.Env``, or the single env of a ``SyncVectorEnv``) is the env this class wraps. Needs only gymnasium.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys

import gymnasium as gym

#: Where the entry file came from (``user/name@<sha>:<path>``) and where it is, inside ``source/``.
SOURCE = "{{SOURCE}}"
SOURCE_ENTRY = "{{SOURCE_ENTRY}}"

#: The start of every message of a broken contract (hub-envs turns it into its typed error).
CONTRACT = "breaks LeRobot's EnvHub contract"


class _SourceLoader(importlib.machinery.SourceFileLoader):
    """The entry file from its source alone: no bytecode cache read or written next to the repo's files."""

    def get_code(self, fullname):
        path = self.get_filename(fullname)
        return self.source_to_code(self.get_data(path), path)

    def set_data(self, *args, **kwargs):
        pass


def source_module():
    """The entry file, imported the way LeRobot's ``make_env`` imports it (a top-level module of its own), once."""
    name = f"{__name__}__source"  # unique to this package: one per repo, commit and entry file
    if name in sys.modules:
        return sys.modules[name]
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "source", *SOURCE_ENTRY.split("/"))
    loader = _SourceLoader(name, path)
    spec = importlib.util.spec_from_file_location(name, path, loader=loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


def call_make_env(n_envs=1, use_async_envs=False):
    """What the entry file's ``make_env`` returns (no ``cfg``: as LeRobot calls it for a repo id string)."""
    make_env = getattr(source_module(), "make_env", None)
    if not callable(make_env):
        raise TypeError(
            f"{SOURCE} {CONTRACT}: {SOURCE_ENTRY} defines no make_env(n_envs, use_async_envs, cfg=None) function. "
            f"Name the file that does after ':' (user/name:path/to/file.py)."
        )
    return make_env(n_envs=n_envs, use_async_envs=use_async_envs)


def single_env(result):
    """The one env of a ``make_env(n_envs=1, use_async_envs=False)`` result, or a TypeError naming what is wrong."""
    if isinstance(result, dict):
        tasks = [(s, t, v) for s, by_task in result.items() if isinstance(by_task, dict) for t, v in by_task.items()]
        if len(tasks) != 1 or not all(isinstance(by_task, dict) for by_task in result.values()):
            for vec in (v for _, _, v in tasks):
                getattr(vec, "close", lambda: None)()
            raise TypeError(
                f"{SOURCE} {CONTRACT} for one env: make_env returned the suite form with {len(tasks)} tasks "
                f"({', '.join(f'{s}/{t}' for s, t, _ in tasks[:6])}); a plain repo loads as one env. Name an entry "
                f"file that makes one task (user/name:path/to/task.py)."
            )
        result = tasks[0][2]
    if isinstance(result, gym.vector.SyncVectorEnv) and len(result.envs) == 1:
        return result.envs[0]
    if isinstance(result, gym.vector.VectorEnv):
        n = getattr(result, "num_envs", "?")
        result.close()
        raise TypeError(
            f"{SOURCE} {CONTRACT} for one env: make_env(n_envs=1, use_async_envs=False) returned a "
            f"{type(result).__name__} of {n} env(s); return a SyncVectorEnv of n_envs envs (or a gym.Env)."
        )
    if isinstance(result, gym.Env):
        return result
    raise TypeError(
        f"{SOURCE} {CONTRACT}: make_env returned {type(result).__name__}, not a gym.Env, a gym.vector.VectorEnv or "
        f"{{suite: {{task_id: VectorEnv}}}}."
    )


class PlainEnv(gym.Wrapper):
    """The env the entry file's ``make_env`` builds, as one ``gym.Env`` (its own wrappers kept).

    Args:
        render_mode: accepted for gymnasium's ``make``; the env renders in the mode its ``make_env`` gave it.
    """

    def __init__(self, render_mode=None, **kwargs):
        if kwargs:
            raise TypeError(f"{SOURCE}: make_env takes no env keyword arguments; got {sorted(kwargs)}.")
        super().__init__(single_env(call_make_env()))
        for name in ("task", "task_description"):  # what LeRobot's add_envs_task reads, through wrappers
            try:
                setattr(self, name, self.env.get_wrapper_attr(name))
            except AttributeError:
                pass
