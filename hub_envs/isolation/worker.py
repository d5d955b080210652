"""The worker process of an isolated env: imports the env's code, runs its envs, answers the parent.

Started by :mod:`hub_envs.isolation.proxy` as ``python -P -c "from hub_envs.isolation.worker import main;
main()" <fd> <page> <wake>`` (a fresh interpreter, never a fork of the parent, which may hold torch and
threads), with the parent's ``sys.path`` as ``PYTHONPATH`` so it imports the same hub-envs. A sandboxed
worker starts as ``python -S -P -c "from hub_envs.isolation.sandbox import boot; boot()" ...`` instead: it
enters its sandbox before the interpreter's ``site`` runs, then :func:`serve` as here. ``<fd>`` is its end
of a socketpair, the others the shared page and the wake-up socket of its :mod:`~hub_envs.isolation.doorbell`
(a single env's short messages travel in the page, the others in the socket). The first message is the init
dict (repo@sha, snapshot folder, env entry point, sandbox settings); then one request, one answer
(:mod:`hub_envs.isolation.protocol`).

It never outlives the parent: ``PR_SET_PDEATHSIG`` (SIGKILL when the parent dies, set before anything
else runs) and, as a second line, the socket: EOF on it ends the worker. A process the env's code forks
never answers: every answer is sent only by the worker's own pid (a forked child is ended instead).

The env's code is imported exactly as in-process (:func:`hub_envs.importing.import_env_folder`: sources
only, no bytecode) from the snapshot folder the parent verified (or, sandboxed, from the private copy
:mod:`hub_envs.isolation.sandbox` verified again); the env's config and lerobot are never imported here.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import time
from functools import partial
from typing import Any

from hub_envs.isolation.doorbell import SPINNING, WORKER, Doorbell, SpinBudget
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


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)``: the kernel sends ``sig`` to this process when its parent dies."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(1, int(sig), 0, 0, 0) == 0  # PR_SET_PDEATHSIG = 1
    except Exception:  # pragma: no cover - not Linux
        return False


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


class Server:
    """Holds the envs of one worker (single envs by index, plus at most one vector slice) and serves requests."""

    def __init__(self, init: dict[str, Any], conn):
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

        import numpy as np

        from hub_envs.isolation.vector import _Buffers

        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        try:
            _, fds, _, _ = socket.recv_fds(sock, 1, n_fds)
        finally:
            sock.close()
        self.fast_buffers = _Buffers(leaves, 1, fds=fds)
        dtype, shape = np.dtype(action_dtype), tuple(action_shape)
        self.fast_action = (dtype, int(np.prod(shape, dtype=np.int64)), None if len(shape) == 1 else shape)

    def fast_step(self, data: bytes):
        import numpy as np

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
        from hub_envs.isolation.vector import WorkerSlice

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

    # -- the config with a user's field values (LeRobot's --env.<field> flags on an isolated load) --
    def op_config(self, entry_point: str, overrides: dict) -> dict:
        """The config's values (:func:`hub_envs.envconfig.encode_config`) with ``overrides`` set before its
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


def serve(conn, bell: Doorbell, init: dict[str, Any]) -> None:
    from hub_envs.isolation.affinity import NO_CPU, Follower

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
            os._exit(70)


def main(argv: list[str] | None = None) -> None:
    from multiprocessing.connection import Connection

    set_parent_death_signal()
    try:  # never real-time (inherited from a parent some library made so): a busy env must not starve its watchdog
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        pass
    argv = sys.argv[1:] if argv is None else argv
    conn = Connection(int(argv[0]))
    bell = Doorbell((int(argv[1]), int(argv[2])), sock_fd=conn.fileno(), side=WORKER)
    if os.getppid() == 1:  # the parent died before the death signal was armed
        os._exit(0)
    init = pickle.loads(bell.receive(None, 0.0, lambda _deadline: conn.recv_bytes()))
    if init.get("sandbox"):  # fail closed: a sandboxed worker enters its sandbox before its site runs (sandbox.boot)
        os.write(2, b"hub-envs worker: a sandboxed worker starts through hub_envs.isolation.sandbox.boot\n")
        os._exit(71)
    serve(conn, bell, init)
    os._exit(0)


if __name__ == "__main__":
    main()
