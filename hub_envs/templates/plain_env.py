"""An env of a plain LeRobot EnvHub repo (no hub_env.json), written by hub-envs. Do not edit: it is regenerated.

The repo's own files are in ``source/``, unchanged; its entry file's ``make_env(n_envs, use_async_envs, cfg=None)``
builds the env (LeRobot's EnvHub contract), called with ``n_envs=1, use_async_envs=False``: the one env it returns
(a ``gym.Env``, or the single env of a ``SyncVectorEnv``; for the suite form ``{suite: {task_id: VectorEnv}}``, the
env of the task the config names) is the env this class wraps. Needs only gymnasium.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import re
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


#: A task name hub-envs can use (what LeRobot's ``--env.task=a,b`` can list: no comma), one line of printable text.
_TASK_NAME = re.compile(r"^[^,\x00-\x1f\x7f]{1,200}$")


def suite_entries(result):
    """``[(suite, task_id, env)]`` of a ``{suite: {task_id: VectorEnv}}`` result, in its order (a TypeError when a suite
    is not a dict, or there is no task)."""
    if not result or not all(isinstance(by_task, dict) for by_task in result.values()):
        for by_task in result.values():
            for vec in by_task.values() if isinstance(by_task, dict) else [by_task]:
                getattr(vec, "close", lambda: None)()
        raise TypeError(
            f"{SOURCE} {CONTRACT}: make_env returned a dict that is not {{suite: {{task_id: VectorEnv}}}} "
            f"(keys {', '.join(repr(k) for k in list(result)[:6])})."
        )
    entries = [(suite, task_id, vec) for suite, by_task in result.items() for task_id, vec in by_task.items()]
    if not entries:
        raise TypeError(f"{SOURCE} {CONTRACT}: make_env returned a suite with no task ({', '.join(map(repr, result))}).")
    return entries


def _first_attr(env, name):
    """A string attribute of a task's (first) env, where LeRobot's ``add_envs_task`` reads it, or None."""
    try:
        if isinstance(env, gym.vector.SyncVectorEnv):
            value = env.envs[0].get_wrapper_attr(name)
        elif isinstance(env, gym.vector.VectorEnv):
            value = env.call(name)[0]
        else:
            value = env.get_wrapper_attr(name)
    except (AttributeError, IndexError, NotImplementedError):
        return None
    return value if isinstance(value, str) else None


def describe_entries(entries):
    """Each task of a suite: ``{suite, task_id, task, instruction}``. A task's name is its env's ``task`` (LeRobot's
    LIBERO and Meta-World envs put the task's name there) when every task has a distinct one hub-envs can use, else
    ``<suite>/<task_id>``; its instruction is its env's ``task_description``, else its ``task`` (what ``lerobot-eval``
    gives a policy), else its name."""
    named = [_first_attr(vec, "task") for _, _, vec in entries]
    usable = all(n is not None and _TASK_NAME.match(n) and n == n.strip() for n in named) and len(set(named)) == len(named)
    out = []
    for (suite, task_id, vec), said in zip(entries, named):
        name = said if usable else f"{suite}/{task_id}"
        instruction = _first_attr(vec, "task_description") or said or name  # what lerobot-eval gives a policy
        out.append({"suite": suite, "task_id": task_id, "task": name, "instruction": instruction})
    return out


def describe_suite():
    """The tasks of the entry file's suite (``describe_entries``), or ``[]`` when ``make_env`` returns one env or a
    suite of one task. Makes every env once (``n_envs=1``) and closes them."""
    result = call_make_env()
    if not isinstance(result, dict):
        getattr(result, "close", lambda: None)()
        return []
    entries = suite_entries(result)
    try:
        return describe_entries(entries) if len(entries) > 1 else []
    finally:
        for _, _, vec in entries:
            vec.close()


def choose_task(result, task):
    """The env of ``task`` in a suite-form result (the others closed): the first task when ``task`` is None; a
    non-suite result, or a suite of one task, as it is."""
    if not isinstance(result, dict):
        return result
    entries = suite_entries(result)
    if len(entries) == 1:
        return entries[0][2]
    names = [d["task"] for d in describe_entries(entries)]
    if task is not None and task not in names:
        for _, _, vec in entries:
            vec.close()
        raise ValueError(f"{SOURCE}: {task!r} is not one of its tasks; they are {', '.join(repr(n) for n in names)}.")
    chosen = names.index(task) if task is not None else 0
    for i, (_, _, vec) in enumerate(entries):
        if i != chosen:
            vec.close()
    return entries[chosen][2]


def single_env(result):
    """The one env of a ``make_env(n_envs=1, use_async_envs=False)`` result (a suite's: one task of it, chosen by
    ``choose_task``), or a TypeError naming what is wrong."""
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
        task: for a ``make_env`` returning a suite (``{suite: {task_id: VectorEnv}}``), the task to make (a name of
            ``describe_suite``; None: the first); ignored for one env.
    """

    def __init__(self, render_mode=None, task=None, **kwargs):
        if kwargs:
            raise TypeError(f"{SOURCE}: make_env takes no env keyword arguments; got {sorted(kwargs)}.")
        super().__init__(single_env(choose_task(call_make_env(), task)))
        for name in ("task", "task_description"):  # what LeRobot's add_envs_task reads, through wrappers
            try:
                setattr(self, name, self.env.get_wrapper_attr(name))
            except AttributeError:
                pass
