"""``make_vec`` for isolated envs: :class:`IsolatedVectorEnv`, ``n_envs`` copies of an env split over worker processes,
one message per worker per step, observations through shared memory (:mod:`~hub_envs.isolation.buffers`).

It answers exactly as the in-process ``SyncVectorEnv`` of the same envs (seeds ``seed + i``, next-step autoreset,
batched observations, rewards, flags and infos); see ``docs/isolation.md`` for how its workers wait.

Example:
    >>> vec = loaded.make_vec(8)          # with load_env(..., isolation="process")   # doctest: +SKIP
    >>> obs, infos = vec.reset(seed=0)                                                 # doctest: +SKIP
"""

from __future__ import annotations

import math
from copy import deepcopy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array, iterate

from hub_envs.errors import ConfigError
from hub_envs.isolation.affinity import NO_CPU, unpin
from hub_envs.isolation.buffers import ObservationBuffers, box_leaves
from hub_envs.isolation.doorbell import SPIN, WaitChooser, available_cpus
from hub_envs.isolation.options import IsolationOptions
from hub_envs.isolation.protocol import FAST_HEADER
from hub_envs.isolation.proxy import WAYS, EnvTarget, Worker, begin_wait, warn_unsent_metadata

try:
    from gymnasium.vector import AutoresetMode
except ImportError:  # pragma: no cover - gymnasium < 1.1
    AutoresetMode = None


def _is_vector_step(answer: Any, n: int) -> bool:
    """Whether a worker's answer to a vector step is one for ``n`` envs (``WorkerSlice.step``'s layout)."""
    if type(answer) is not tuple or len(answer) != 5 or type(answer[3]) is not list or len(answer[3]) != n:
        return False
    return all(type(a) is np.ndarray and a.shape == (n,) and a.dtype == d for a, d in zip(answer[:3], _STEP_DTYPES))


_STEP_DTYPES = (np.dtype(np.float64), np.dtype(np.bool_), np.dtype(np.bool_))


class IsolatedVectorEnv(gym.vector.VectorEnv):
    """``n_envs`` copies of an isolated env, batched like ``SyncVectorEnv`` (see the module docstring).

    Args:
        target: the env's code.
        options: how it runs; ``envs_per_worker`` (0: spread over all CPUs but one, which stays the caller's).
        n_envs: how many envs.
        gym_id: the registered id (each env is built in its worker as ``gym.make`` builds it).
        kwargs: the envs' constructor arguments.
        max_episode_steps: the TimeLimit of each env.
        disable_env_checker: as ``gym.make``'s.

    Raises:
        ConfigError: ``n_envs`` or ``envs_per_worker`` is not positive.
        EnvCrashedError, EnvTimeoutError, RemoteEnvError: a worker failed to start or to build its envs (every
            worker started is stopped).
    """

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
        self._buffers: ObservationBuffers | None = None
        self._closed_vec = False
        self._waits = WaitChooser(WAYS)
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
            leaves = box_leaves(self.single_observation_space)
            if leaves is not None:
                self._buffers = ObservationBuffers(leaves, n_envs)
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
        """The worker processes, in the order of the envs they hold."""
        return list(self._workers)

    def _all(self, op: str, per_worker_args: list[tuple]) -> list[Any]:
        for w, args in zip(self._workers, per_worker_args, strict=True):
            w.send(op, *args)
        return self._gather(op)

    def _gather(self, op: str, spin: bool = True) -> list[Any]:
        out, error = [], None
        for w in self._workers:
            try:
                out.append(w.receive(op, timeout=self._options.call_timeout, spin=spin))
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
        """Reset every env, as ``SyncVectorEnv`` does.

        Args:
            seed: one seed (env ``i`` gets ``seed + i``), one per env, or None.
            options: every env's reset options (``reset_mask`` is refused: envs autoreset on the next step).

        Returns:
            ``(observations, infos)``, batched.

        Raises:
            ValueError: a list of seeds of another length than ``num_envs``.
            ConfigError: ``reset_mask`` in ``options``.
        """
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
        self._waits.forget_last()  # the time from the last step to the next one holds this reset
        answers = self._all("vreset", [(seeds[o : o + c], options) for o, c in self._slices])
        infos: dict = {}
        i = 0
        for env_infos, _ in answers:
            for info in env_infos:
                infos = self._add_info(infos, info, i)
                i += 1
        return self._obs(answers), infos

    def step(self, actions: Any) -> tuple:
        """Step every env (one message per worker; an env whose episode ended resets instead, next-step autoreset).

        Args:
            actions: the batched actions.

        Returns:
            ``(observations, rewards, terminations, truncations, infos)``, batched as ``SyncVectorEnv`` batches them.

        Raises:
            RemoteEnvError: the env raised (the worker lives on).
            EnvCrashedError: the worker died, or sent what is not an answer (it is stopped).
            EnvTimeoutError: no answer within the step timeout (the worker is killed).
            AnswerTooLargeError: the answer would build far more than it weighs (the worker lives on).

        The first worker that failed raises; the others' answers are read.
        """
        space = self.single_action_space
        if (
            isinstance(space, spaces.Box)
            and type(actions) is np.ndarray
            and actions.dtype == space.dtype
            and actions.shape == (self.num_envs, *space.shape)
        ):  # raw bytes, one message per worker
            # busy-waiting (a CPU for everyone): no pinning; else the first worker may sleep where this thread waits
            # (see affinity) and the others, sent theirs first, run wherever the scheduler finds a CPU
            way, cpu, saved = begin_wait(self._waits, self._workers[0].spins)
            spinning = way == SPIN
            try:
                for k in range(len(self._workers) - 1, -1, -1):
                    w, (o, c) = self._workers[k], self._slices[k]
                    w.send_raw(FAST_HEADER.pack(b"v", cpu if k == 0 or spinning else NO_CPU) + actions[o : o + c].tobytes())
                answers = self._gather("vstep", spin=spinning)
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
                raise w.garbled("vstep", ValueError(f"a vector step answer of type {type(answer).__name__}"))
            r, te, tr, env_infos, _ = answer
            n = len(env_infos)
            rewards[i : i + n], terms[i : i + n], truncs[i : i + n] = r, te, tr
            for j in range(n):
                infos = self._add_info(infos, env_infos[j], i + j)
            i += n
        return self._obs(answers), rewards, terms, truncs, infos

    def render(self) -> tuple:
        """Every env's ``render()``."""
        frames = self._all("vcall", [("render", ())] * len(self._workers))
        return tuple(f for fs in frames for f in fs)

    def call(self, name: str, *args: Any) -> tuple:
        """``render``, ``get_state`` or ``reset_to`` of every env, in its worker.

        Args:
            name: the method.
            *args: its arguments (the same for every env).

        Returns:
            One result per env.

        Raises:
            RemoteEnvError: an env's method raised (the worker lives on).
            EnvCrashedError: a worker died, or sent what is not an answer (it is stopped).
            EnvTimeoutError: no answer within the step timeout (the worker is killed).
        """
        results = self._all("vcall", [(name, args)] * len(self._workers))
        return tuple(r for rs in results for r in rs)

    def close_extras(self, **kwargs: Any) -> None:
        self.close()

    def close(self, **kwargs: Any) -> None:
        """Close every env and worker (again: nothing)."""
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
