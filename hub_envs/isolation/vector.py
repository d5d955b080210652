"""``make_vec`` for isolated envs: several envs per worker, one message per vector step, observations
through shared memory.

:class:`IsolatedVectorEnv` is a ``gym.vector.VectorEnv`` that behaves as the in-process
``SyncVectorEnv`` of ``n_envs`` copies (same seeds ``seed + i``, same next-step autoreset, same batched
observations, rewards, flags and infos), with the envs split over worker processes
(``envs_per_worker``; default: over all CPUs but one, which stays the caller's). Each step sends every worker
one message with its envs' actions; the workers step in parallel, write each observation into per-key shared
buffers (one ``memfd`` per leaf ``Box`` of the observation space, ``(n_envs, *shape)`` of its dtype, handed to
the workers as file descriptors, so no name in ``/dev/shm`` and nothing for a sandbox to reach) and answer with
rewards, flags and infos only (a fixed binary layout, :func:`~hub_envs.isolation.protocol.vector_answer`).
Observation spaces with leaves other than ``Box`` travel in the answers.

**Waiting.** With fewer workers than CPUs, the caller and the workers busy-wait for each other's messages in a
shared page (:mod:`~hub_envs.isolation.doorbell`, bounded and adaptive as for a single env); else they sleep.
On a VM a sleeping process woken from another CPU costs ~50-65 us a wake-up: 8 pendulums (~27 us a step each)
in one busy-waiting worker ran 0.84-0.93 of the in-process SyncVectorEnv's steps/s on 2 CPUs, in two sleeping
workers 0.64-0.65. An env whose step is long gains more from running in parallel than it loses to wake-ups (8
hovers, ~150 us a step: one worker 0.85, two 1.09 on 2 CPUs): set ``envs_per_worker`` to split them.

Inside a worker (:class:`WorkerSlice`) every env is built as ``gym.make`` builds it in-process (TimeLimit,
OrderEnforcing, the env checker as registered).

Example:
    >>> vec = loaded.make_vec(8)          # with load_env(..., isolation="process")   # doctest: +SKIP
    >>> obs, infos = vec.reset(seed=0)                                                 # doctest: +SKIP
"""

from __future__ import annotations

import math
import mmap
import os
from copy import deepcopy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array, iterate

from hub_envs.errors import ConfigError
from hub_envs.isolation.affinity import NO_CPU, pin_here, unpin
from hub_envs.isolation.doorbell import SPINNING, available_cpus, sealed_memfd
from hub_envs.isolation.protocol import FAST_HEADER
from hub_envs.isolation.proxy import EnvTarget, IsolationOptions, Worker, warn_unsent_metadata

try:
    from gymnasium.vector import AutoresetMode
except ImportError:  # pragma: no cover - gymnasium < 1.1
    AutoresetMode = None


def _box_leaves(space: spaces.Space, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], spaces.Box]] | None:
    """``[(key path, Box)]`` for a Box or a (nested) Dict of Boxes; None for any other space."""
    if isinstance(space, spaces.Box):
        return [(prefix, space)]
    if isinstance(space, spaces.Dict):
        out = []
        for k, sub in space.spaces.items():
            leaves = _box_leaves(sub, (*prefix, k))
            if leaves is None:
                return None
            out += leaves
        return out
    return None


def _get(obs: Any, path: tuple[str, ...]) -> Any:
    for k in path:
        obs = obs[k]
    return obs


class _Buffers:
    """Per-leaf shared arrays ``(n, *shape)`` in memfds (created by the parent, mapped by the workers)."""

    def __init__(self, leaves, n: int, fds: list[int] | None = None):
        self.leaves = leaves
        self.fds: list[int] = []
        self.maps: list[mmap.mmap] = []
        self.arrays: list[np.ndarray] = []
        for i, (path, box) in enumerate(leaves):
            nbytes = max(1, n * int(np.prod(box.shape, dtype=np.int64)) * np.dtype(box.dtype).itemsize)
            if fds is None:
                fd = sealed_memfd(f"hub-envs-obs-{'.'.join(path) or 'obs'}", nbytes)  # a worker cannot shrink it
            else:
                fd = fds[i]
            self.fds.append(fd)
            m = mmap.mmap(fd, nbytes)
            self.maps.append(m)
            self.arrays.append(np.ndarray((n, *box.shape), dtype=box.dtype, buffer=m))
        # what an observation must be to travel here (checked at every step, so precomputed): the whole
        # observation one array (``_root``), a dict of arrays (``_flat``) or nested dicts (``_tree``), keys in order
        self._root = len(leaves) == 1 and leaves[0][0] == ()
        layout = [(path, arr, arr.dtype, arr.shape[1:]) for (path, _), arr in zip(leaves, self.arrays, strict=True)]
        self._flat = [(p[0], a, d, s) for p, a, d, s in layout] if all(len(p) == 1 for p, *_ in layout) else None
        self._keys = tuple(k for k, *_ in self._flat) if self._flat is not None else ()
        self._tree: dict = {}
        for path, arr, dtype, shape in layout:
            node = self._tree
            for k in path[:-1]:
                node = node.setdefault(k, {})
            if path:
                node[path[-1]] = (arr, dtype, shape)

    def write_exact(self, index: int, obs: Any) -> bool:
        """Write ``obs`` only if reading it back gives exactly it (arrays of exactly these dtypes and shapes; dicts
        of exactly these keys, in this order); False (nothing written) otherwise."""
        if self._root:
            arr = self.arrays[0]
            if type(obs) is not np.ndarray or obs.dtype != arr.dtype or obs.shape != arr.shape[1:]:
                return False
            arr[index] = obs
            return True
        flat = self._flat
        if flat is not None:  # the usual case, kept short: it runs at every step of an isolated env
            if type(obs) is not dict or tuple(obs) != self._keys:
                return False
            for key, _, dtype, shape in flat:
                v = obs[key]
                if type(v) is not np.ndarray or v.dtype != dtype or v.shape != shape:
                    return False
            for key, arr, _, _ in flat:
                arr[index] = obs[key]
            return True
        if not self._same_layout(obs, self._tree):
            return False
        self.write(index, obs)
        return True

    @classmethod
    def _same_layout(cls, obs: Any, tree: dict) -> bool:
        if type(obs) is not dict or tuple(obs) != tuple(tree):
            return False
        for k, v in obs.items():
            node = tree[k]
            if type(node) is dict:
                if not cls._same_layout(v, node):
                    return False
            elif type(v) is not np.ndarray or v.dtype != node[1] or v.shape != node[2]:
                return False
        return True

    def read_one(self, index: int = 0) -> Any:
        """A copy of one env's observation."""
        # arr[index, ...]: an array even for a 0-d leaf (arr[index] would be a numpy scalar)
        if self._root:
            return self.arrays[0][index, ...].copy()
        if self._flat is not None:
            return {key: arr[index, ...].copy() for key, arr, _, _ in self._flat}
        out: dict = {}
        for (path, _), arr in zip(self.leaves, self.arrays, strict=True):
            d = out
            for k in path[:-1]:
                d = d.setdefault(k, {})
            d[path[-1]] = arr[index, ...].copy()
        return out

    def write(self, index: int, obs: Any) -> None:
        for (path, _), arr in zip(self.leaves, self.arrays, strict=True):
            arr[index] = _get(obs, path)

    def read(self) -> Any:
        """A copy of the batch, shaped like ``batch_space(single_observation_space)`` (dicts of arrays)."""
        if self._root:
            return self.arrays[0].copy()
        out: dict = {}
        for (path, _), arr in zip(self.leaves, self.arrays, strict=True):
            d = out
            for k in path[:-1]:
                d = d.setdefault(k, {})
            d[path[-1]] = arr.copy()
        return out

    def close(self) -> None:
        self.arrays.clear()
        self._flat, self._tree = None, {}  # their views of the maps too
        for m in self.maps:
            try:
                m.close()
            except BufferError:  # pragma: no cover - an array still views it
                pass
        self.maps.clear()
        for fd in self.fds:
            try:
                os.close(fd)
            except OSError:
                pass
        self.fds.clear()


class WorkerSlice:
    """The envs ``offset .. offset + count`` of a vector env, inside one worker process."""

    def __init__(self, env_class, spec: dict[str, Any]):
        from gymnasium.envs.registration import EnvSpec

        env_spec = EnvSpec(
            id=spec["gym_id"],
            entry_point=env_class,
            max_episode_steps=spec["max_episode_steps"],
            kwargs=dict(spec["kwargs"]),
            disable_env_checker=spec["disable_env_checker"],
        )
        self.envs = [gym.make(env_spec) for _ in range(spec["count"])]
        self.autoreset = [False] * len(self.envs)
        self.buffers: _Buffers | None = None
        self.offset = spec["offset"]
        space = self.envs[0].action_space
        self.action_layout = (np.dtype(space.dtype), tuple(space.shape)) if isinstance(space, spaces.Box) else None

    def attach_buffers(self, leaves, n_envs: int, fds: list[int]) -> None:
        self.buffers = _Buffers(leaves, n_envs, fds=fds)

    def _out(self, i: int, obs: Any, unshared: list) -> None:
        if self.buffers is not None:
            self.buffers.write(self.offset + i, obs)
        else:
            unshared.append(obs)

    def reset(self, seeds, options):
        infos, unshared = [], []
        for i, (env, seed) in enumerate(zip(self.envs, seeds, strict=True)):
            obs, info = env.reset(seed=seed, options=options)
            self._out(i, obs, unshared)
            infos.append(info)
        self.autoreset = [False] * len(self.envs)
        return infos, unshared

    def step(self, actions):
        """``(rewards, terminations, truncations, infos, observations not in shared memory)``: rewards and flags as
        the float64 and bool arrays ``SyncVectorEnv`` stores them in (assigned item by item, as it does)."""
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

    def step_raw(self, data: bytes):
        """``step`` of actions sent as raw bytes (:data:`FAST_HEADER` + this slice's rows of the batched actions)."""
        dtype, shape = self.action_layout
        actions = np.frombuffer(data, dtype=dtype, offset=FAST_HEADER.size).reshape((len(self.envs), *shape)).copy()
        return self.step(list(actions))

    def call(self, name: str, args: tuple):
        if name not in ("render", "get_state", "reset_to"):
            raise AttributeError(f"{name} cannot be called through an isolated vector env")
        return [getattr(env.unwrapped if name != "render" else env, name)(*args) for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()
        if self.buffers is not None:
            self.buffers.close()


def _is_vector_step(answer: Any, n: int) -> bool:
    """Whether a worker's answer to a vector step is one for ``n`` envs (:meth:`WorkerSlice.step`)."""
    if type(answer) is not tuple or len(answer) != 5 or type(answer[3]) is not list or len(answer[3]) != n:
        return False
    return all(type(a) is np.ndarray and a.shape == (n,) and a.dtype == d for a, d in zip(answer[:3], _STEP_DTYPES))


_STEP_DTYPES = (np.dtype(np.float64), np.dtype(np.bool_), np.dtype(np.bool_))


class IsolatedVectorEnv(gym.vector.VectorEnv):
    """``n_envs`` copies of an isolated env, batched like ``SyncVectorEnv`` (see the module docstring)."""

    def __init__(
        self,
        target: EnvTarget,
        options: IsolationOptions,
        n_envs: int,
        *,
        gym_id: str,
        kwargs: dict[str, Any],
        max_episode_steps: int | None,
        disable_env_checker: bool,
    ):
        if n_envs < 1:
            raise ConfigError(f"n_envs must be at least 1, got {n_envs}.")
        cpus = available_cpus()
        # by default one CPU stays the caller's (it busy-waits for the answers) and the others run workers
        per = options.envs_per_worker or math.ceil(n_envs / max(1, min(n_envs, cpus - 1)))
        if per < 1:
            raise ConfigError(f"envs_per_worker={options.envs_per_worker}: pass a positive number (or 0 for the default).")
        self._target, self._options = target, options
        self.num_envs = n_envs
        self._workers: list[Worker] = []
        self._slices: list[tuple[int, int]] = []
        self._buffers: _Buffers | None = None
        self._closed_vec = False
        try:
            counts = [min(per, n_envs - o) for o in range(0, n_envs, per)]
            spin = len(counts) < cpus  # a CPU for each worker and one for the caller: both sides busy-wait
            for _ in counts:  # side by side: each imports the env's code at the same time
                self._workers.append(Worker(target, options, wait=False, spin=spin))
            for w in self._workers:
                w.ready()
            offset = 0
            for w, count in zip(self._workers, counts, strict=True):
                spec = {
                    "gym_id": gym_id,
                    "kwargs": dict(kwargs),
                    "max_episode_steps": max_episode_steps,
                    "disable_env_checker": disable_env_checker,
                    "count": count,
                    "offset": offset,
                }
                w.send("vmake", spec)
                self._slices.append((offset, count))
                offset += count
            descs = [w.receive("vmake", timeout=options.start_timeout) for w in self._workers]
            desc = descs[0]
            self.single_observation_space = desc["observation_space"]
            self.single_action_space = desc["action_space"]
            leaves = _box_leaves(self.single_observation_space)
            if leaves is not None:
                self._buffers = _Buffers(leaves, n_envs)
                for w in self._workers:
                    w.send("vbuffers", leaves, n_envs, len(self._buffers.fds))
                    w.send_fds(self._buffers.fds)
                for w in self._workers:
                    w.receive("vbuffers", timeout=options.start_timeout)
            self.metadata = dict(desc["metadata"])
            warn_unsent_metadata(desc, target.where)
            if AutoresetMode is not None:
                self.metadata["autoreset_mode"] = AutoresetMode.NEXT_STEP
            self.render_mode = desc["render_mode"]
            self.observation_space = batch_space(self.single_observation_space, n_envs)
            self.action_space = batch_space(self.single_action_space, n_envs)
            self._unshared_out = create_empty_array(self.single_observation_space, n_envs) if leaves is None else None
        except BaseException:
            self.close()
            raise

    @property
    def workers(self) -> list[Worker]:
        return list(self._workers)

    def _all(self, op: str, per_worker_args: list[tuple]) -> list[Any]:
        for w, args in zip(self._workers, per_worker_args, strict=True):
            w.send(op, *args)
        return self._gather(op)

    def _gather(self, op: str) -> list[Any]:
        out, error = [], None
        for w in self._workers:
            try:
                out.append(w.receive(op, timeout=self._options.call_timeout))
            except Exception as e:  # keep reading the others, so every worker stays in step
                out.append(None)
                error = error or e
            except KeyboardInterrupt:  # the answers not read would come out of step: stop every worker
                for other in self._workers:
                    other.interrupted(op)
                raise
        if error is not None:
            raise error
        return out

    def _obs(self, answers: list) -> Any:
        if self._buffers is not None:
            return self._buffers.read()
        flat = [o for a in answers for o in a[-1]]
        return deepcopy(concatenate(self.single_observation_space, flat, self._unshared_out))

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(
                f"If seeds are passed as a list the length must match num_envs={self.num_envs} but got length={len(seeds)}."
            )
        if options is not None and "reset_mask" in options:
            raise ConfigError("reset_mask is not supported by an isolated vector env (it autoresets on the next step).")
        answers = self._all("vreset", [(seeds[o : o + c], options) for o, c in self._slices])
        infos: dict = {}
        i = 0
        for env_infos, _ in answers:
            for info in env_infos:
                infos = self._add_info(infos, info, i)
                i += 1
        return self._obs(answers), infos

    def step(self, actions):
        space = self.single_action_space
        if (
            isinstance(space, spaces.Box)
            and type(actions) is np.ndarray
            and actions.dtype == space.dtype
            and actions.shape == (self.num_envs, *space.shape)
        ):  # raw bytes, one message per worker
            # busy-waiting (a CPU for everyone): no pinning; else the first worker sleeps where this thread waits
            # (see affinity) and the others, sent theirs first, run wherever the scheduler finds a CPU
            spinning = self._workers[0].spins
            cpu, saved = (SPINNING, None) if spinning else pin_here()
            try:
                for k in range(len(self._workers) - 1, -1, -1):
                    w, (o, c) = self._workers[k], self._slices[k]
                    w.send_raw(FAST_HEADER.pack(b"v", cpu if k == 0 or spinning else NO_CPU) + actions[o : o + c].tobytes())
                answers = self._gather("vstep")
            finally:
                unpin(saved)
        else:
            per_env = list(iterate(self.action_space, actions))
            answers = self._all("vstep", [(per_env[o : o + c],) for o, c in self._slices])
        rewards = np.zeros(self.num_envs, dtype=np.float64)
        terms = np.zeros(self.num_envs, dtype=np.bool_)
        truncs = np.zeros(self.num_envs, dtype=np.bool_)
        infos: dict = {}
        i = 0
        for w, (_, c), answer in zip(self._workers, self._slices, answers, strict=True):
            if not _is_vector_step(answer, c):
                raise w._garbled("vstep", ValueError(f"a vector step answer of type {type(answer).__name__}"))
            r, te, tr, env_infos, _ = answer
            n = len(env_infos)
            rewards[i : i + n], terms[i : i + n], truncs[i : i + n] = r, te, tr
            for j in range(n):
                infos = self._add_info(infos, env_infos[j], i + j)
            i += n
        return self._obs(answers), rewards, terms, truncs, infos

    def render(self):
        frames = self._all("vcall", [("render", ())] * len(self._workers))
        return tuple(f for fs in frames for f in fs)

    def call(self, name: str, *args: Any) -> tuple:
        results = self._all("vcall", [(name, args)] * len(self._workers))
        return tuple(r for rs in results for r in rs)

    def close_extras(self, **kwargs: Any) -> None:
        self.close()

    def close(self, **kwargs: Any) -> None:
        if self._closed_vec:
            return
        self._closed_vec = True
        for w in self._workers:
            if w.alive:
                try:
                    w.request("vclose", timeout=self._options.call_timeout or 30.0)
                except Exception:
                    pass
            w.close()
        if self._buffers is not None:
            self._buffers.close()
        self.closed = True

    def __repr__(self) -> str:
        return f"IsolatedVectorEnv({self._target.where}, num_envs={self.num_envs}, workers={len(self._workers)})"
