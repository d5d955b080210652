"""The episode engine: seeded episodes of an env (each fully determined by its seed, its policy and ``max_steps``), run in
worker processes and recorded step by step; the results do not depend on the number of workers.

Example:
    >>> import gymnasium as gym
    >>> from hub_envs.harness.rollout import run_episodes
    >>> eps = run_episodes(lambda: gym.make("Pendulum-v1"), seeds=[0, 1], max_steps=50, progress=False)
    >>> [e.length for e in eps], sorted(eps[0].observations), eps[0].actions.shape
    ([50, 50], ['observation'], (50, 1))
    >>> again = run_episodes(lambda: gym.make("Pendulum-v1"), seeds=[0, 1], max_steps=50,
    ...                      workers=2, progress=False)
    >>> again == eps
    True
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import itertools
import multiprocessing
import os
import sys
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing.util import Finalize
from typing import Any

import numpy as np
from huggingface_hub.utils import tqdm  # respects HF_HUB_DISABLE_PROGRESS_BARS, like hub downloads

from hub_envs._compat import live_children, terminate_new_children
from hub_envs.errors import ConfigError, EnvCodeError
from hub_envs.harness.episode import SeededEpisode, exception_text

__all__ = ["EpisodeRollout", "run_episodes", "iter_episodes", "flatten_observation"]

OBSERVATION_KEY = "observation"  # key of a non-dict observation
_BUFFER_BYTES = 16 * 2**20  # preallocate up to this many bytes per recorded key, grow beyond


@dataclass(eq=False)
class EpisodeRollout:
    """Everything recorded in one episode. Arrays share their first axis: the step index."""

    index: int
    seed: int
    observations: dict[str, np.ndarray]
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    is_success: np.ndarray
    states: np.ndarray | None = None
    #: why ``states`` is None although the env has ``get_state`` (its values could not be kept), else None
    states_problem: str | None = None

    @property
    def length(self) -> int:
        """Number of steps (frames) in the episode."""
        return int(self.actions.shape[0])

    @property
    def episode_return(self) -> float:
        """Sum of the rewards."""
        return float(np.sum(self.rewards, dtype=np.float64))

    @property
    def success(self) -> bool:
        """True if ``info["is_success"]`` was true at any step (LeRobot's eval convention)."""
        return bool(np.any(self.is_success))

    def _arrays(self) -> list[tuple[str, np.ndarray | None]]:
        obs = [(f"observations/{k}", self.observations[k]) for k in sorted(self.observations)]
        return obs + [
            ("actions", self.actions),
            ("rewards", self.rewards),
            ("terminated", self.terminated),
            ("truncated", self.truncated),
            ("is_success", self.is_success),
            ("states", self.states),
        ]

    def digest(self) -> str:
        """sha256 over index, seed and every array (name, dtype, shape, bytes): equal iff identical."""
        h = hashlib.sha256(f"{self.index}\0{self.seed}\0".encode())
        for name, arr in self._arrays():
            if arr is None:
                h.update(f"{name}\0None\0".encode())
                continue
            arr = np.ascontiguousarray(arr)
            h.update(f"{name}\0{arr.dtype.str}\0{arr.shape}\0".encode())
            h.update(arr.tobytes())
        return h.hexdigest()

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EpisodeRollout):
            return NotImplemented
        if (self.index, self.seed, sorted(self.observations)) != (other.index, other.seed, sorted(other.observations)):
            return False
        for (_, a), (_, b) in zip(self._arrays(), other._arrays(), strict=True):
            if (a is None) != (b is None):
                return False
            if a is not None and (a.dtype != b.dtype or a.shape != b.shape or not np.array_equal(a, b, equal_nan=True)):
                return False
        return True

    __hash__ = None  # mutable arrays inside


# --- observations -----------------------------------------------------------------------------


def _layout(obs: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, tuple[str, ...]]]:
    """(flat key, path) for every leaf of a (nested) dict observation."""
    if isinstance(obs, Mapping):
        out = []
        for k, v in obs.items():
            out.extend(_layout(v, (*prefix, str(k))))
        return out
    if not prefix:
        return [(OBSERVATION_KEY, ())]
    return [("/".join(prefix), prefix)]


def flatten_observation(obs: Any) -> dict[str, Any]:
    """Flatten a (nested) dict observation to ``{"a/b": leaf}``; a non-dict one to ``{"observation": obs}``.

    >>> flatten_observation({"agent_pos": 1, "pixels": {"top": 2}})
    {'agent_pos': 1, 'pixels/top': 2}
    """
    return {key: _get(obs, path) for key, path in _layout(obs)}


def _get(obs: Any, path: tuple[str, ...]) -> Any:
    for p in path:
        obs = obs[p]
    return obs


class _Buffer:
    """A growable (capacity, *shape) array written row by row (copies, so env-side reuse is safe)."""

    __slots__ = ("data", "n")

    def __init__(self, first: Any, max_steps: int):
        first = np.asarray(first)
        per_row = max(first.nbytes, 1)
        cap = max_steps if per_row * max_steps <= _BUFFER_BYTES else max(1, min(max_steps, _BUFFER_BYTES // per_row, 64))
        self.data = np.empty((cap, *first.shape), dtype=first.dtype)
        self.n = 0

    def append(self, value: Any) -> None:
        if self.n == self.data.shape[0]:
            grown = np.empty((self.data.shape[0] * 2, *self.data.shape[1:]), dtype=self.data.dtype)
            grown[: self.n] = self.data
            self.data = grown
        self.data[self.n] = value
        self.n += 1

    def array(self) -> np.ndarray:
        return self.data if self.n == self.data.shape[0] else self.data[: self.n].copy()


# --- one episode ------------------------------------------------------------------------------


def _resolve_get_state(env: Any) -> Callable[[], Any] | None:
    getter = getattr(env, "get_wrapper_attr", None)
    if getter is not None:
        try:
            return getter("get_state")
        except AttributeError:
            return None
    return getattr(env, "get_state", None)


class EpisodeRunner:
    """Holds one env (created on first use) and runs episodes on it: what each worker of the engine (and of a Ray
    backend) runs; ``policy`` as :func:`run_episodes` takes it."""

    def __init__(self, make_env: Callable[[], Any], max_steps: int, policy: Any, record_states: bool, n_episodes: int):
        self.make_env = make_env
        self.max_steps = max_steps
        self.record_states = record_states
        self.n_episodes = n_episodes
        self.policy_fn: Callable[[Any, int], Any] | None = None
        self.shared_actions: np.ndarray | None = None
        self.episode_actions: list[np.ndarray] | None = None
        if policy is None:
            pass
        elif callable(policy):
            self.policy_fn = policy
        elif isinstance(policy, np.ndarray):
            self.shared_actions = policy
        elif isinstance(policy, (list, tuple)) and policy and all(isinstance(p, np.ndarray) for p in policy):
            self.episode_actions = list(policy)  # disambiguated against the action space on first use
        elif (
            isinstance(policy, (list, tuple))
            and policy
            and all(p is None or isinstance(p, np.ndarray) for p in policy)
            and any(p is None for p in policy)
        ):
            self.episode_actions = list(policy)  # per episode: recorded actions, or None for seeded random actions
        else:
            try:
                self.shared_actions = np.asarray(policy)
            except Exception as exc:  # noqa: BLE001
                raise ConfigError(
                    f"policy must be None, a callable (obs, step_index) -> action, an action array (T, *A) "
                    f"or a list with one action array per episode; got {type(policy).__name__}."
                ) from exc
        self.env: Any = None
        self.get_state: Callable[[], Any] | None = None

    def _ensure_env(self) -> Any:
        if self.env is None:
            try:
                self.env = self.make_env()
            except Exception as exc:
                raise EnvCodeError(
                    f"make_env() raised {exception_text(exc)}. Fix the env constructor; nothing was recorded."
                ) from exc
            if not hasattr(self.env, "reset") or not hasattr(self.env, "step") or not hasattr(self.env, "action_space"):
                raise EnvCodeError(
                    f"make_env() returned {type(self.env).__name__}, which is not a gymnasium env "
                    "(it needs reset, step and action_space). Return a gymnasium.Env from make_env."
                )
            self.get_state = _resolve_get_state(self.env) if self.record_states else None
        return self.env

    def close(self) -> None:
        """Close the runner's env (an error closing it is ignored: it must not mask results or the original error)."""
        if self.env is not None:
            try:
                self.env.close()
            except Exception:  # noqa: BLE001  - closing must not mask results or the original error
                pass
            self.env = None

    def _actions_for(self, index: int, action_ndim: int) -> np.ndarray | None:
        if self.episode_actions is not None:
            per_episode = all(a is None or a.ndim == action_ndim + 1 for a in self.episode_actions)
            if per_episode or any(a is None for a in self.episode_actions):
                if not per_episode:
                    raise ConfigError(
                        "policy mixes None with action arrays: then every array must be one episode's (T, *action_shape) actions."
                    )
                if len(self.episode_actions) != self.n_episodes:
                    raise ConfigError(
                        f"policy has {len(self.episode_actions)} action arrays but there are {self.n_episodes} "
                        "seeds. Pass one (T, *action_shape) array per episode, in seed order."
                    )
                return self.episode_actions[index]
            self.shared_actions = np.stack(self.episode_actions)
            self.episode_actions = None
        return self.shared_actions

    def run(self, index: int, seed: int, *, episode: int | None = None) -> EpisodeRollout:
        """Run one episode of this runner's seeds.

        Args:
            index: the episode's index among the runner's seeds (its recorded actions, when replayed).
            seed: its reset seed.
            episode: the number it is recorded and reported under (default ``index``; a shard of a larger run passes its
                global index).

        Returns:
            The :class:`EpisodeRollout`.

        Raises:
            EnvCodeError: the env raised, or produced a NaN/inf observation or reward.
        """
        env = self._ensure_env()
        number = index if episode is None else int(episode)
        where = f"episode {number} (seed {seed})"
        episode_run = SeededEpisode(env, seed, where=where)
        obs, space = episode_run.obs, episode_run.space
        action_shape = getattr(space, "shape", None) or ()
        fixed = self._actions_for(index, len(action_shape))
        max_steps = self.max_steps if fixed is None else min(self.max_steps, len(fixed))
        if max_steps < 1:
            raise ConfigError(f"{where}: no actions to replay (the action array for this episode is empty).")

        layout = _layout(obs)
        try:
            obs_bufs = {k: _Buffer(_get(obs, p), max_steps) for k, p in layout}
        except Exception as exc:
            raise EnvCodeError(f"{where}: the reset observation is not made of arrays: {exception_text(exc)}.") from exc
        # how to record each leaf at step t: (buffer rows, path); path None = the whole obs, str = obs[key],
        # tuple = nested. Rows are written in place (one row per step) while the buffers hold max_steps rows.
        record = [(obs_bufs[k].data, None if not p else p[0] if len(p) == 1 else p) for k, p in layout]
        in_place = all(b.data.shape[0] >= max_steps for b in obs_bufs.values())
        get_state = self.get_state
        state_buf: _Buffer | None = None
        state_rows: np.ndarray | None = None
        states_problem: str | None = None
        act_buf: _Buffer | None = None
        rewards: list[float] = []
        terms: list[bool] = []
        truncs: list[bool] = []
        succ: list[bool] = []
        policy_fn = self.policy_fn
        sample = episode_run.sample
        env_step = env.step  # not episode_run.step: its bookkeeping is a quarter of this loop's own time
        actions = list(fixed[:max_steps]) if fixed is not None else None  # one row view each, made up front
        t = 0
        for t in range(max_steps):
            # record the observation before action t
            try:
                if in_place:
                    for rows, p in record:
                        rows[t] = obs if p is None else obs[p] if type(p) is str else _get(obs, p)
                else:
                    for k, p in layout:
                        obs_bufs[k].append(_get(obs, p))
            except Exception as exc:
                what = "reset" if t == 0 else f"step {t - 1}"
                raise EnvCodeError(
                    f"{where}: the observation returned by {what} does not match the reset observation's "
                    f"keys/shapes/dtypes: {exception_text(exc)}. Keep the observation layout fixed."
                ) from exc
            if get_state is not None:
                try:
                    state = get_state()
                except Exception as exc:
                    raise EnvCodeError(f"{where}, step {t}: env.get_state() raised {exception_text(exc)}.") from exc
                try:
                    if state_rows is not None:
                        state_rows[t] = state
                    elif state_buf is None:
                        state_buf = _Buffer(state, max_steps)
                        state_buf.append(state)
                        state_rows = state_buf.data if state_buf.data.shape[0] >= max_steps else None
                    else:
                        state_buf.append(state)
                except (TypeError, ValueError) as exc:  # a state of another shape or kind than the first
                    states_problem = f"get_state() at step {t} returned a value unlike step 0's ({exception_text(exc)})"
                    get_state, state_buf, state_rows = None, None, None

            if actions is not None:
                action = actions[t]
            elif policy_fn is not None:
                action = policy_fn(obs, t)
            else:
                action = sample()
            try:
                obs, reward, terminated, truncated, info = env_step(action)
            except Exception as exc:
                raise episode_run.step_error(exc, t) from exc
            if actions is None:  # replayed actions are copied once at the end
                if act_buf is None:
                    act_buf = _Buffer(action, max_steps)
                act_buf.append(action)
            rewards.append(reward)
            terminated, truncated = bool(terminated), bool(truncated)  # once: kept and tested
            terms.append(terminated)
            truncs.append(truncated)
            succ.append(bool(info.get("is_success", False)) if info else False)
            if terminated or truncated:
                break
        if in_place:
            for b in obs_bufs.values():
                b.n = t + 1
        if state_rows is not None and state_buf is not None:
            state_buf.n = t + 1
        if not terms[-1] and not truncs[-1]:
            truncs[-1] = True  # cut by max_steps: a time-limit truncation

        observations = {k: b.array() for k, b in obs_bufs.items()}
        try:
            reward_arr = np.asarray(rewards, dtype=np.float64)
        except Exception as exc:
            raise EnvCodeError(f"{where}: env.step returned a reward that is not a number: {exception_text(exc)}.") from exc
        _check_finite(where, observations, reward_arr)
        return EpisodeRollout(
            index=number,
            seed=seed,
            observations=observations,
            actions=act_buf.array() if fixed is None else np.array(fixed[: len(rewards)]),
            rewards=reward_arr,
            terminated=np.asarray(terms, dtype=bool),
            truncated=np.asarray(truncs, dtype=bool),
            is_success=np.asarray(succ, dtype=bool),
            states=state_buf.array() if state_buf is not None else None,
            states_problem=states_problem,
        )


def _first_bad_step(arr: np.ndarray) -> int | None:
    if arr.dtype.kind not in "fc":
        return None
    flat = arr.reshape(arr.shape[0], -1)
    ok = np.isfinite(flat).all(axis=1)
    if ok.all():
        return None
    return int(np.flatnonzero(~ok)[0])


def _check_finite(where: str, observations: dict[str, np.ndarray], rewards: np.ndarray) -> None:
    for key, arr in observations.items():
        bad = _first_bad_step(arr)
        if bad is not None:
            src = "env.reset" if bad == 0 else f"env.step at step {bad - 1}"
            raise EnvCodeError(
                f"{where}: observation '{key}' contains NaN or inf at step {bad} (returned by {src}). "
                "Fix the env so observations stay finite (clip, or terminate the episode)."
            )
    bad = _first_bad_step(rewards)
    if bad is not None:
        raise EnvCodeError(f"{where}: the reward of step {bad} is NaN or inf. Fix the env's reward computation.")


# --- many episodes, maybe in worker processes ---------------------------------------------------

_FORK_STATES: dict[int, tuple] = {}  # token -> runner args, inherited by forked workers
_TOKENS = itertools.count()
_WORKER: EpisodeRunner | None = None
_WORKER_FILES: str | None = None  # in a worker: the path prefix of the files its big observations travel in

#: Observations at least this big go from a worker to the parent through a file in /dev/shm (memory) instead of
#: the result pipe: pickled through the pipe, an episode of camera frames cost the worker about as much CPU as
#: stepping the env, and the parent as much again to read it (a few MiB per episode). /dev/shm full or missing:
#: the pipe, as before.
_FILE_MIN_BYTES = 256 * 1024
_SHM = "/dev/shm"


@dataclass(frozen=True)
class _ArrayFile:
    """An array a worker wrote to ``path`` (raw bytes, C order); :meth:`load` reads it back and removes the file."""

    path: str
    shape: tuple[int, ...]
    dtype: str

    def load(self) -> np.ndarray:
        arr = np.empty(self.shape, dtype=np.dtype(self.dtype))
        try:
            with open(self.path, "rb", buffering=0) as f:
                view, done = memoryview(arr.reshape(-1)).cast("B"), 0
                while done < len(view):
                    n = f.readinto(view[done:])
                    if not n:
                        raise EnvCodeError(
                            f"{self.path}: a worker process's observation file was cut short (the worker was stopped "
                            "while writing it?). Run with workers=1 to run the episodes in this process."
                        )
                    done += n
        finally:
            with contextlib.suppress(OSError):
                os.unlink(self.path)
        return arr


def _files_prefix(token: int) -> str | None:
    """Where the workers of pool ``token`` write big observations (None: through the pipe)."""
    return f"{_SHM}/hub-envs-rollout-{os.getpid()}-{token}-" if os.path.isdir(_SHM) and os.access(_SHM, os.W_OK) else None


def _to_file(arr: np.ndarray, path: str) -> Any:
    """``arr`` written to ``path`` (an :class:`_ArrayFile`), or ``arr`` itself when it is small or cannot be written."""
    if not isinstance(arr, np.ndarray) or arr.nbytes < _FILE_MIN_BYTES or arr.dtype.hasobject:
        return arr
    arr = np.ascontiguousarray(arr)
    try:
        with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600), "wb", buffering=0) as f:  # this user only
            view = memoryview(arr.reshape(-1)).cast("B")
            while view:
                view = view[f.write(view) :]
    except OSError:  # /dev/shm full (a container's is small): the pipe
        with contextlib.suppress(OSError):
            os.unlink(path)
        return arr
    return _ArrayFile(path, tuple(arr.shape), arr.dtype.str)


def _worker_init(token: int | None, args: tuple | None, files: str | None = None) -> None:
    global _WORKER, _WORKER_FILES
    if args is None:
        args = _FORK_STATES[token]
    _WORKER = EpisodeRunner(*args)
    _WORKER_FILES = files
    try:  # close the env when the worker exits (atexit does not run in pool workers)
        Finalize(_WORKER, _WORKER.close, exitpriority=10)
    except Exception:  # noqa: BLE001
        pass


def _worker_run(index: int, seed: int) -> EpisodeRollout:
    assert _WORKER is not None
    rollout = _WORKER.run(index, seed)
    if _WORKER_FILES is not None:
        prefix = f"{_WORKER_FILES}{os.getpid()}-{index}-"
        rollout.observations = {k: _to_file(v, f"{prefix}{n}") for n, (k, v) in enumerate(rollout.observations.items())}
    return rollout


def _received(rollout: EpisodeRollout) -> EpisodeRollout:
    """A worker's rollout with the observations it wrote to files read back (and the files removed)."""
    if any(isinstance(v, _ArrayFile) for v in rollout.observations.values()):
        rollout.observations = {k: v.load() if isinstance(v, _ArrayFile) else v for k, v in rollout.observations.items()}
    return rollout


def check_seeds(seeds: Sequence[int]) -> list[int]:
    """The seeds as ints, each checked.

    Args:
        seeds: reset seeds.

    Returns:
        The seeds as a list of ints.

    Raises:
        ConfigError: a seed that is not a non-negative integer.
    """
    out = []
    for i, s in enumerate(seeds):
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0:
            raise ConfigError(f"seeds[{i}] = {s!r}: seeds must be non-negative integers (gymnasium's reset(seed=...)).")
        out.append(int(s))
    return out


def progress_bar(total: int, desc: str, enabled: bool):
    """A progress bar counting episodes (huggingface_hub's tqdm: it respects ``HF_HUB_DISABLE_PROGRESS_BARS``).

    Args:
        total: the episodes.
        desc: the bar's label.
        enabled: False: a silent bar.
    """
    return tqdm(total=total, desc=desc, unit="ep", disable=not enabled, leave=False)


def iter_episodes(
    make_env: Callable[[], Any],
    seeds: Sequence[int],
    *,
    max_steps: int,
    policy: Any = None,
    record_states: bool = False,
    workers: int = 1,
    progress: bool = True,
    desc: str = "rollouts",
) -> Iterator[EpisodeRollout]:
    """Like :func:`run_episodes`, but yields the rollouts one by one in episode order (bounded memory): with
    ``workers > 1`` at most ``2 * workers`` finished episodes wait for the consumer; closing the iterator early stops the
    workers.

    Args:
        make_env, seeds, max_steps, policy, record_states, workers, progress, desc: as :func:`run_episodes`.

    Returns:
        An iterator of :class:`EpisodeRollout`.

    Raises:
        ConfigError: invalid seeds, max_steps or workers (at once, not on the first ``next()``).
        EnvCodeError: an episode raised (when it is consumed).
    """
    seeds = check_seeds(seeds)  # validate now, not on the first next()
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ConfigError(f"max_steps={max_steps!r}: pass a positive integer.")
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ConfigError(f"workers={workers!r}: pass a positive integer.")
    args = (make_env, int(max_steps), policy, bool(record_states), len(seeds))
    return _iter(args, seeds, min(int(workers), max(1, len(seeds))), progress, desc)


def _iter(args: tuple, seeds: list[int], workers: int, progress: bool, desc: str) -> Iterator[EpisodeRollout]:
    bar = progress_bar(len(seeds), desc, progress)
    try:
        if workers == 1:
            runner = EpisodeRunner(*args)
            try:
                for i, seed in enumerate(seeds):
                    rollout = runner.run(i, seed)
                    bar.update(1)
                    yield rollout
            finally:
                runner.close()
        else:
            yield from _iter_pool(args, seeds, workers, bar)
    finally:
        bar.close()


def _iter_pool(args: tuple, seeds: list[int], workers: int, bar) -> Iterator[EpisodeRollout]:
    files = None
    if sys.platform.startswith("linux") and "fork" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("fork")
        token = next(_TOKENS)
        _FORK_STATES[token] = args
        files = _files_prefix(token)
        initargs: tuple = (token, None, files)
    else:  # spawn: make_env and policy must be picklable
        ctx = multiprocessing.get_context("spawn")
        token = None
        initargs = (None, args)
    children_before = live_children()
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=initargs)
    finished = False
    pending: deque = deque()
    try:
        todo = iter(enumerate(seeds))
        window = 2 * workers
        for i, seed in itertools.islice(todo, window):
            pending.append((i, seed, pool.submit(_worker_run, i, seed)))
        while pending:
            i, seed, fut = pending.popleft()
            try:
                rollout = _received(fut.result())
            except BrokenProcessPool as exc:
                raise EnvCodeError(
                    f"A worker process died while running episode {i} (seed {seed}) or one near it: the env "
                    "probably crashed the interpreter (segfault, os._exit or out of memory). "
                    "Run with workers=1 to see the failure in this process."
                ) from exc
            nxt = next(todo, None)
            if nxt is not None:
                pending.append((nxt[0], nxt[1], pool.submit(_worker_run, *nxt)))
            bar.update(1)
            yield rollout
        finished = True
    finally:
        if finished:
            pool.shutdown(wait=True)
        else:
            for *_, fut in pending:
                fut.cancel()
            pool.shutdown(wait=False, cancel_futures=True)
            terminate_new_children(children_before)
            if files is not None:  # stopped before the files they may still write are swept
                for proc in multiprocessing.active_children():
                    if proc.pid not in children_before:
                        proc.join(timeout=2)
        if token is not None:
            _FORK_STATES.pop(token, None)
        if files is not None:  # what no one read: episodes not consumed, a worker that died after writing
            for path in glob.glob(glob.escape(files) + "*"):
                with contextlib.suppress(OSError):
                    os.unlink(path)


def run_episodes(make_env: Callable[[], Any], seeds: Sequence[int], **options: Any) -> list[EpisodeRollout]:
    """Run one episode per seed and return the rollouts in seed order.

    Args:
        make_env: zero-argument callable returning a gymnasium env. Called once per worker; the env is reused across that
            worker's episodes. With ``workers > 1`` on Linux the pool forks, so it need not be picklable.
        seeds: one non-negative int per episode; episode ``i`` runs ``env.reset(seed=seeds[i])`` and
            ``env.action_space.seed(seeds[i])``.
        options: :func:`iter_episodes`' keywords:
            ``max_steps`` (at most this many steps per episode; the env may end it earlier);
            ``policy`` (``None``: seeded uniform random actions from ``env.action_space.sample()``; a callable
            ``(obs, step_index) -> action``; an action array ``(T, *A)`` applied to every episode; or a list with one
            ``(T_i, *A)`` array, or ``None`` for seeded random actions, per episode: replay, at most as many steps as
            there are actions);
            ``record_states`` (also record ``env.get_state()`` before each action, when the env has it);
            ``workers`` (processes; results are identical for any value);
            ``progress`` (a progress bar, hidden by ``HF_HUB_DISABLE_PROGRESS_BARS=1`` too);
            ``desc`` (the bar's label).

    Returns:
        One :class:`EpisodeRollout` per seed.

    Raises:
        EnvCodeError: the env raised in make_env/reset/step, or produced NaN/inf observations or rewards.
        ConfigError: invalid seeds, max_steps, workers or policy.
    """
    return list(iter_episodes(make_env, seeds, **options))
