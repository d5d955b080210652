"""The worker process of an isolated env: imports the env's code, runs its envs, answers the parent.

Started by :mod:`~hub_envs.isolation.proxy` as a fresh interpreter (never a fork of the parent), or through
:func:`hub_envs.isolation.sandbox.boot` when sandboxed; one request, one answer (:mod:`~hub_envs.isolation.protocol`).
The env's code is imported exactly as in-process, from the snapshot folder the parent verified; its config and
lerobot are never imported here (but for :meth:`Server.op_config`).
"""

from __future__ import annotations

import os
import pickle
import sys
import time
from functools import partial
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from hub_envs.isolation.affinity import NO_CPU, Follower
from hub_envs.isolation.buffers import Leaves, ObservationBuffers
from hub_envs.isolation.doorbell import SPINNING, Doorbell, SpinBudget
from hub_envs.isolation.lifetime import ENTER_FAILED_EXIT, FATAL_EXIT, attach_to_parent
from hub_envs.isolation.protocol import FAST_HEADER, encode_answer, error_info, fast_answer, vector_answer
from hub_envs.isolation.wire import Unsendable, encode

STATE_METHODS = ("get_state", "reset_to")
#: what the parts of an answer are, to name the one the wire cannot carry (by op; b"s"/b"v": the fast steps)
_PARTS = {
    "reset": ("observation", "info"),
    "step": ("observation", "reward", "terminated", "truncated", "info"),
    b"s": ("reward", "terminated", "truncated", "info", "observation"),
    "vreset": ("infos", "observations"),
    "vstep": ("rewards", "terminations", "truncations", "infos", "observations"),
    b"v": ("rewards", "terminations", "truncations", "infos", "observations"),
}


def _unsendable(key: Any, result: Any, error: Exception) -> str:
    """Which part of an answer the wire cannot carry, and why (``info['x'] is of type ...``)."""
    parts = _PARTS.get(key)
    if parts and type(result) is tuple:
        for part, value in zip(parts, result, strict=False):
            try:
                encode(value, part)
            except Unsendable as found:
                return str(found)
    return str(error)


def _describe(env: Any) -> dict[str, Any]:
    raw = env.unwrapped
    obs_space, act_space = env.observation_space, env.action_space
    metadata, unsent = {}, []
    for key, value in dict(getattr(raw, "metadata", {}) or {}).items():  # what the wire cannot carry stays here
        try:
            encode([key, value])
            metadata[key] = value
        except Unsendable:
            unsent.append(repr(key))
    return {
        "observation_space": obs_space,
        "action_space": act_space,
        "metadata": metadata,
        "metadata_unsent": unsent,
        "render_mode": getattr(raw, "render_mode", None),
        "state_methods": [m for m in STATE_METHODS if callable(getattr(raw, m, None))],
        "pid": os.getpid(),
    }


class WorkerSlice:
    """The envs ``offset .. offset + count`` of a vector env, inside one worker process, each built as ``gym.make``
    builds it in-process (TimeLimit, OrderEnforcing, the env checker as registered).

    Args:
        env_class: the env's entry point (imported from its verified code).
        spec: from the parent's ``vmake``: ``gym_id``, ``kwargs``, ``max_episode_steps``, ``disable_env_checker``,
            ``count`` and ``offset``.
    """

    def __init__(self, env_class: Any, spec: dict[str, Any]):
        env_spec = EnvSpec(
            id=spec["gym_id"],
            entry_point=env_class,
            max_episode_steps=spec["max_episode_steps"],
            kwargs=dict(spec["kwargs"]),
            disable_env_checker=spec["disable_env_checker"],
        )
        self.envs = [gym.make(env_spec) for _ in range(spec["count"])]
        self.autoreset = [False] * len(self.envs)
        self.buffers: ObservationBuffers | None = None
        self.offset = spec["offset"]
        space = self.envs[0].action_space
        self.action_layout = (np.dtype(space.dtype), tuple(space.shape)) if isinstance(space, spaces.Box) else None

    def attach_buffers(self, leaves: Leaves, n_envs: int, fds: list[int]) -> None:
        """Write observations into the parent's shared buffers from now on.

        Args:
            leaves: the observation space's :func:`~hub_envs.isolation.buffers.box_leaves`.
            n_envs: the whole vector env's (rows of the buffers; this slice writes from its offset).
            fds: the buffers' memfds, one per leaf.
        """
        self.buffers = ObservationBuffers(leaves, n_envs, fds=fds)

    def _out(self, i: int, obs: Any, unshared: list) -> None:
        if self.buffers is not None:
            self.buffers.write(self.offset + i, obs)
        else:
            unshared.append(obs)

    def reset(self, seeds: list[int | None], options: dict[str, Any] | None) -> tuple[list, list]:
        """Reset every env of the slice.

        Args:
            seeds: one per env.
            options: every env's reset options.

        Returns:
            ``(infos, observations not in shared memory)``.
        """
        infos, unshared = [], []
        for i, (env, seed) in enumerate(zip(self.envs, seeds, strict=True)):
            obs, info = env.reset(seed=seed, options=options)
            self._out(i, obs, unshared)
            infos.append(info)
        self.autoreset = [False] * len(self.envs)
        return infos, unshared

    def step(self, actions: list) -> tuple:
        """Step every env of the slice (an env whose episode ended resets instead, as ``SyncVectorEnv`` does).

        Args:
            actions: one action per env of the slice.

        Returns:
            ``(rewards, terminations, truncations, infos, observations not in shared memory)``: rewards and flags
            as the float64 and bool arrays ``SyncVectorEnv`` stores them in (assigned item by item, as it does).
        """
        n = len(self.envs)
        rewards, terms, truncs = np.zeros(n, np.float64), np.zeros(n, np.bool_), np.zeros(n, np.bool_)
        infos, unshared = [], []
        for i, (env, action) in enumerate(zip(self.envs, actions, strict=True)):
            if self.autoreset[i]:
                obs, info = env.reset()
                r, te, tr = 0.0, False, False
            else:
                obs, r, te, tr, info = env.step(action)
            self._out(i, obs, unshared)
            rewards[i], terms[i], truncs[i] = r, te, tr
            infos.append(info)
            self.autoreset[i] = bool(te or tr)
        return rewards, terms, truncs, infos, unshared

    def step_raw(self, data: bytes) -> tuple:
        """:meth:`step` of actions sent as raw bytes.

        Args:
            data: :data:`~hub_envs.isolation.protocol.FAST_HEADER` and this slice's rows of the batched actions.

        Returns:
            As :meth:`step`.
        """
        dtype, shape = self.action_layout
        actions = np.frombuffer(data, dtype=dtype, offset=FAST_HEADER.size).reshape((len(self.envs), *shape)).copy()
        return self.step(list(actions))

    def call(self, name: str, args: tuple) -> list:
        """A method of every env of the slice.

        Args:
            name: ``render``, ``get_state`` or ``reset_to``.
            args: its arguments.

        Returns:
            One result per env.

        Raises:
            AttributeError: any other name.
        """
        if name not in ("render", "get_state", "reset_to"):
            raise AttributeError(f"{name} cannot be called through an isolated vector env")
        return [getattr(env.unwrapped if name != "render" else env, name)(*args) for env in self.envs]

    def close(self) -> None:
        """Close the envs and unmap the shared buffers."""
        for env in self.envs:
            env.close()
        if self.buffers is not None:
            self.buffers.close()


class Server:
    """The envs of one worker (single envs by index, at most one vector slice): ``op_<name>(*args)`` answers the
    request ``(name, *args)`` (:mod:`~hub_envs.isolation.protocol`).

    Args:
        init: the parent's init message (``where``, ``path``, ``key``, ``entry_point``): the env's code is imported
            from ``path`` here.
        conn: the worker's end of the socketpair (file descriptors arrive on it).

    Raises:
        Exception: whatever importing the env's code raised (the worker reports it and stops).
    """

    def __init__(self, init: dict[str, Any], conn: Connection):
        from hub_envs.envcode.importing import import_env_folder, resolve_entry_point

        self.where = init["where"]
        self.conn = conn
        package = self.package = import_env_folder(init["path"], init["key"])
        self.env_class = resolve_entry_point(package, init["entry_point"], where=f"{self.where}: env entry point")
        self.envs: dict[int, Any] = {}
        self.vec = None

    # -- single envs --
    def op_make(self, idx: int, kwargs: dict) -> dict:
        env = self.env_class(**kwargs)
        self.envs[idx] = env
        return _describe(env)

    def op_reset(self, idx: int, seed, options):
        return self.envs[idx].reset(seed=seed, options=options)

    def op_step(self, idx: int, action):
        return self.envs[idx].step(action)

    # -- the fast path of a single env's step: raw action bytes in, observation into shared memory --
    def op_fast(self, leaves, action_dtype: str, action_shape: tuple, n_fds: int):
        """Arm the fast path of env 0: map its observation buffers (fds follow the message)."""
        import socket

        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        try:
            _, fds, _, _ = socket.recv_fds(sock, 1, n_fds)
        finally:
            sock.close()
        self.fast_buffers = ObservationBuffers(leaves, 1, fds=fds)
        dtype, shape = np.dtype(action_dtype), tuple(action_shape)
        self.fast_action = (dtype, int(np.prod(shape, dtype=np.int64)), None if len(shape) == 1 else shape)

    def fast_step(self, data: bytes):
        dtype, count, shape = self.fast_action
        raw = np.frombuffer(data, dtype, count, FAST_HEADER.size)  # too short: ValueError
        action = (raw if shape is None else raw.reshape(shape)).copy()
        obs, reward, terminated, truncated, info = self.envs[0].step(action)
        # the observation goes through shared memory only if that keeps it exactly (types, dtypes, shapes, key order)
        shared = self.fast_buffers.write_exact(0, obs)
        return reward, terminated, truncated, info, None if shared else obs, shared

    def op_render(self, idx: int):
        return self.envs[idx].render()

    def op_call(self, idx: int, name: str, args: tuple):
        if name not in STATE_METHODS:
            raise AttributeError(f"{name} cannot be called through an isolated env")
        return getattr(self.envs[idx].unwrapped, name)(*args)

    def op_close(self, idx: int):
        env = self.envs.pop(idx, None)
        if env is not None:
            env.close()

    # -- a slice of a vector env --
    def op_vmake(self, spec: dict) -> dict:
        self.vec = WorkerSlice(self.env_class, spec)
        return _describe(self.vec.envs[0])

    def op_vbuffers(self, leaves, n_envs: int, n_fds: int):
        import socket

        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        try:
            _, fds, _, _ = socket.recv_fds(sock, 1, n_fds)
        finally:
            sock.close()
        self.vec.attach_buffers(leaves, n_envs, fds)

    def op_vreset(self, seeds, options):
        return self.vec.reset(seeds, options)

    def op_vstep(self, actions):
        return self.vec.step(actions)

    def op_vcall(self, name: str, args: tuple):
        return self.vec.call(name, args)

    def op_vclose(self):
        if self.vec is not None:
            self.vec.close()
            self.vec = None

    def op_ping(self):
        return os.getpid()

    # -- what a function of the env's code says about it (a plain EnvHub repo's suite: its tasks) --
    def op_describe(self, entry_point: str) -> Any:
        """What ``entry_point`` (a function of the env's code taking no argument) returns, e.g. the tasks of a plain
        repo's suite (``hub_envs_plain_env:describe_suite``), found where the env's code runs."""
        from hub_envs.envcode.importing import resolve_entry_point

        return resolve_entry_point(self.package, entry_point, where=f"{self.where}: {entry_point}")()

    # -- the config with a user's field values (LeRobot's --env.<field> flags on an isolated load) --
    def op_config(self, entry_point: str, overrides: dict) -> dict:
        """The config's values (:func:`hub_envs.envcode.envconfig.encode_config`) with ``overrides`` set before its
        ``__post_init__``, which runs here, not in the parent. Imports the config module, and so lerobot.
        Answers ``{"values": ...}`` or ``{"error": (hub-envs error class name, message)}``."""
        from hub_envs.envcode.importing import resolve_entry_point
        from hub_envs.errors import HubEnvsError

        try:
            try:
                from hub_envs.envcode.envconfig import encode_config, instantiate_config
            except ImportError as e:
                return {
                    "error": (
                        "IsolationUnavailableError",
                        f"{self.where}: setting config fields ({sorted(overrides)}) runs the env's config class, which "
                        f"needs lerobot, and the worker cannot import it ({e}). With isolation='venv', list lerobot in "
                        f"the env's requirements, or use isolation='process'.",
                    )
                }
            cls = resolve_entry_point(self.package, entry_point, where=f"{self.where}: config entry point")
            return {"values": encode_config(instantiate_config(cls, where=self.where, overrides=overrides))}
        except HubEnvsError as e:
            return {"error": (type(e).__name__, str(e))}


def serve(conn: Connection, bell: Doorbell, init: dict[str, Any]) -> None:
    """Import the env's code, then answer the parent's requests one by one until it says exit or goes away.

    Args:
        conn: the worker's end of the socketpair.
        bell: the worker's end of the shared page beside it.
        init: the parent's init message (:func:`~hub_envs.isolation.lifetime.attach_to_parent`).
    """
    me = os.getpid()

    def answer(data: bytes) -> None:
        bell.send(data, conn.send_bytes)

    def from_socket(_deadline) -> bytes:
        return conn.recv_bytes()

    try:
        server = Server(init, conn)
    except BaseException as e:  # the env's code failed on import: report it, then stop
        answer(encode_answer("err", error_info(e)))
        return
    answer(encode_answer("ok", {"pid": me}))
    follower, cpu = Follower(), NO_CPU
    spin = SpinBudget()
    clock = time.perf_counter
    answered = clock()
    while True:
        budget = spin.seconds() if cpu == SPINNING else 0.0  # only after a step the parent busy-waited for
        try:
            # asleep, wait on the parent's CPU: waking it there is cheap (see affinity)
            data = bell.receive(None, answered + budget if budget else 0.0, from_socket, partial(follower.wait_on, cpu))
        except (EOFError, OSError):
            return  # the parent closed its end (or died)
        follower.woken()
        if spin.active:
            spin.observe(clock() - answered)
        kind = data[:1]
        fast = kind in (b"s", b"v")  # raw action bytes: a single env's step, a vector slice's step
        if fast:
            cpu = FAST_HEADER.unpack_from(data)[1]
        msg = ("step",) if fast else pickle.loads(data)
        op, args = msg[0], msg[1:]
        fatal, result = False, None
        if op == "exit":
            return
        try:
            if fast:
                result = server.fast_step(data) if kind == b"s" else server.vec.step_raw(data)
            else:
                result = getattr(server, f"op_{op}")(*args)
            reply: tuple = ("ok", result)
        except MemoryError as e:  # memory state is suspect (RLIMIT_AS hit): report, then end this worker
            reply, fatal = ("fatal", error_info(e)), True
        except BaseException as e:
            reply = ("err", error_info(e))
        if os.getpid() != me:  # a process the env's code forked came back here: it never answers
            os._exit(0)
        try:
            if kind == b"s" and reply[0] == "ok" and result[5]:  # the observation is in shared memory
                data = fast_answer(*result[:4]) or encode_answer(*reply)
            elif kind == b"v" and reply[0] == "ok" and server.vec.buffers is not None:  # so are the observations
                data = vector_answer(*result[:4])
            else:
                data = encode_answer(*reply)
        except Exception as e:  # an answer the wire cannot carry: say what it was
            why = _unsendable(kind if fast else op, result, e)
            data = encode_answer("err", error_info(TypeError(f"the env's {op} returned something that cannot be sent: {why}")))
        try:
            answer(data)
        except (OSError, EOFError):
            return
        answered = clock()
        if fatal:
            os._exit(FATAL_EXIT)


def main(argv: list[str] | None = None) -> None:
    """A worker's entry point, run as ``python -P -c "...main()" <fd> <page> <wake>``: attach to the parent, then
    :func:`serve` until it says exit or goes away.

    Args:
        argv: the arguments after ``-c`` (default ``sys.argv[1:]``).
    """
    conn, bell, init = attach_to_parent(sys.argv[1:] if argv is None else argv)
    if init.get("sandbox"):  # fail closed: a sandboxed worker enters its sandbox before its site runs (sandbox.boot)
        os.write(2, b"hub-envs worker: a sandboxed worker starts through hub_envs.isolation.sandbox.boot\n")
        os._exit(ENTER_FAILED_EXIT)
    serve(conn, bell, init)
    os._exit(0)


if __name__ == "__main__":
    main()
