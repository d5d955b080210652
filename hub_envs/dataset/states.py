"""Simulator states: the contract an env may offer (:class:`SupportsSimulatorState`), recorded beside a dataset.

A LeRobot dataset holds what a policy sees (observations, actions, rewards), not everything the
simulator's continuation depends on. When the env has ``get_state()`` / ``reset_to(state)``,
push_env also records the full state before each action, so a replay can restore any step exactly
(robomimic's playback: ``reset_to(states[t])``, ``step(actions[t])``, compare with ``t + 1``) and
tell a change in the dynamics at step ``t`` from an error carried over from earlier steps.

The states live in ONE parquet file next to LeRobot's own metadata, ``meta/env_states.parquet``,
which LeRobot's reader ignores and hub-envs' dataset fingerprint covers::

    episode_index  int64
    frame_index    int64
    state          fixed_size_list<float64>[prod(state shape)]

**What a state may be** (the contract, as robomimic's ``EnvBase.get_state`` / ``reset_to``): a numeric numpy
array (bool, int, uint or float) of one fixed shape, at least 1-D, the same for every step and episode,
holding everything the simulator's continuation depends on, and taking it changes nothing (push records
states in the same rollouts its golden fingerprint comes from); ``reset_to(state)`` restores it so that the
next ``step(action)`` gives what it gave when the state was taken. Values are stored as float64, so
integers beyond 2**53 lose precision. Both methods are optional: without them a replay still compares
every step, but cannot restore step ``t`` to tell a change in the dynamics at ``t`` from an error carried
over. A ``get_state`` whose values cannot be recorded (a dict, a scalar, shapes that change) gives a
:class:`~hub_envs.errors.StatesNotRecordedWarning` at push naming why, never a silent "no states".

The state shape and dtype are in the schema metadata (key ``hub_envs``). Written with fixed
parquet options, so the same states give the same bytes.

Example:
    >>> import tempfile, numpy as np
    >>> from hub_envs.dataset.states import read_env_states, write_env_states
    >>> root = tempfile.mkdtemp()
    >>> write_env_states(root, {0: np.zeros((3, 2)), 1: np.ones((2, 2))})
    True
    >>> {k: v.shape for k, v in read_env_states(root).items()}
    {0: (3, 2), 1: (2, 2)}
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from hub_envs.dataset.layout import STATES_PATH
from hub_envs.errors import DatasetError

__all__ = [
    "STATES_PATH",
    "SupportsSimulatorState",
    "EnvStatesWriter",
    "unrecordable_reason",
    "write_env_states",
    "read_env_states",
]

_PARQUET_OPTS = dict(compression="snappy", use_dictionary=False, write_statistics=False, version="2.6")


@runtime_checkable
class SupportsSimulatorState(Protocol):
    """An env (or a wrapper in front of it) whose full simulator state can be taken and restored.

    >>> import numpy as np
    >>> class Ball:
    ...     x = np.zeros(2)
    ...     def get_state(self): return self.x.copy()
    ...     def reset_to(self, state): self.x = np.array(state); return {}
    >>> isinstance(Ball(), SupportsSimulatorState)
    True
    """

    def get_state(self) -> np.ndarray:
        """Everything the continuation depends on, as a numeric array of a fixed shape (module docstring)."""
        ...

    def reset_to(self, state: np.ndarray) -> Any:
        """Restore ``state`` (as ``get_state`` returned it); the next ``step`` continues from there."""
        ...


def _as_state_array(states: Any) -> np.ndarray | None:
    if states is None:
        return None
    arr = np.asarray(states)
    if arr.ndim < 2 or arr.dtype.kind not in "fiub":  # (T, *state shape), the state itself at least 1-D
        return None
    return arr


def unrecordable_reason(states: Mapping[int, Any]) -> str | None:
    """Why ``{episode_index: (T, *state shape) states}`` (as rollouts record them) cannot be written, or None.

    >>> import numpy as np
    >>> unrecordable_reason({0: np.zeros((3, 2)), 1: np.zeros((3, 2))}) is None
    True
    >>> unrecordable_reason({0: np.zeros((3, 2)), 1: np.zeros((3, 4))})
    'get_state() returned arrays of different shapes ((2,) and (4,))'
    """
    if not states:
        return "no episodes were recorded"
    shapes = set()
    for ep, value in states.items():
        if value is None:
            return f"episode {ep} recorded no states"
        arr = np.asarray(value, dtype=object) if not isinstance(value, np.ndarray) else value
        if arr.dtype.kind not in "fiub":
            return f"get_state() returned {_describe_state(value)}, not a numeric array (episode {ep})"
        if arr.ndim < 2:
            return f"get_state() returned a scalar (episode {ep}); return a 1-D array instead"
        shapes.add(tuple(arr.shape[1:]))
    if len(shapes) > 1:
        a, b = sorted(shapes)[:2]
        return f"get_state() returned arrays of different shapes ({a} and {b})"
    return None


def _describe_state(value: Any) -> str:
    first = value[0] if isinstance(value, (list, tuple, np.ndarray)) and len(value) else value
    return f"a {type(first).__name__}" if not isinstance(first, np.ndarray) else f"a {first.dtype} array"


class EnvStatesWriter:
    """Writes the states file (``meta/env_states.parquet`` of a dataset) at ``path`` one episode at a time (push_env's memory does not grow with the
    number of episodes: each episode's states go to disk as it arrives, one row group per episode).

    States are all-or-nothing: the first episode that cannot be recorded (:func:`unrecordable_reason`: no
    states, not numeric, a scalar, another shape than the first episode's) stops the writer and removes the
    partial file; :attr:`reason` says why. :meth:`close` returns whether the file was written.

    >>> import tempfile, numpy as np
    >>> path = Path(tempfile.mkdtemp()) / "env_states.parquet"
    >>> with EnvStatesWriter(path) as w:
    ...     w.add(0, np.zeros((3, 2))); w.add(1, np.zeros((2, 4)))
    >>> w.written, w.reason
    (False, 'get_state() returned arrays of different shapes ((2,) and (4,))')
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._partial = self.path.with_name(self.path.name + ".partial")  # renamed to ``path`` by close()
        self.reason: str | None = None
        self.written = False
        self._writer = None
        self._first: tuple[int, np.ndarray] | None = None  # (episode, its first state) the others must match
        self._episodes = 0

    def add(self, episode_index: int, states: Any) -> None:
        """Append one episode's ``(T, *state_shape)`` states (before each action)."""
        import pyarrow as pa  # heavy: pyarrow
        import pyarrow.parquet as pq  # heavy: pyarrow

        if self.reason is not None:
            return
        reason = unrecordable_reason({int(episode_index): states})
        arr = _as_state_array(states) if reason is None else None
        if reason is None and arr is None:
            reason = f"get_state() returned {_describe_state(states)} (episode {episode_index})"
        if reason is None and len(arr) == 0:
            reason = f"episode {episode_index} recorded no states"
        if reason is None and self._first is not None:
            reason = unrecordable_reason({self._first[0]: self._first[1][None], int(episode_index): arr})
        if reason is not None:
            self._stop(reason)
            return
        width = int(np.prod(arr.shape[1:]))
        if self._writer is None:
            self._first = (int(episode_index), arr[0])
            meta = {"shape": list(arr.shape[1:]), "dtype": str(arr.dtype), "source": "env.get_state() before action t (hub-envs)"}
            schema = pa.schema(
                [("episode_index", pa.int64()), ("frame_index", pa.int64()), ("state", pa.list_(pa.float64(), width))],
                metadata={"hub_envs": json.dumps(meta, sort_keys=True)},
            )
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(self._partial, schema, **_PARQUET_OPTS)
        n = len(arr)
        state_col = pa.FixedSizeListArray.from_arrays(
            pa.array(arr.reshape(n * width).astype(np.float64), type=pa.float64()), width
        )
        table = pa.table(
            {
                "episode_index": np.full(n, int(episode_index), dtype=np.int64),
                "frame_index": np.arange(n, dtype=np.int64),
                "state": state_col,
            },
            schema=self._writer.schema,
        )
        self._writer.write_table(table)
        self._episodes += 1

    def _stop(self, reason: str) -> None:
        self.reason = reason
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._partial.unlink(missing_ok=True)  # only ever our own file: an existing ``path`` is left as it is

    def close(self) -> bool:
        """Finish the file; True when every episode's states were written (and there was at least one)."""
        if self.reason is None and self._episodes == 0:
            self._stop("no episodes were recorded")
        if self._writer is not None:
            self._writer.close()
            self._writer = None
            os.replace(self._partial, self.path)
            self.written = True
        return self.written

    def abort(self) -> None:
        """Give up (an error elsewhere): nothing is left on disk."""
        self._stop(self.reason or "aborted")

    def __enter__(self) -> EnvStatesWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_env_states(root: str | os.PathLike, states: Mapping[int, np.ndarray | None]) -> bool:
    """Write ``{episode_index: (T, *state_shape) array}`` to ``root/meta/env_states.parquet`` (in episode order,
    with :class:`EnvStatesWriter`).

    Returns False (and writes nothing, an existing file left as it is) when :func:`unrecordable_reason` finds a
    reason: states are all-or-nothing, a replay must be able to rely on them.
    """
    with EnvStatesWriter(Path(root) / STATES_PATH) as writer:
        for episode in sorted(states):
            writer.add(episode, states[episode])
    return writer.written


def read_env_states(root: str | os.PathLike) -> dict[int, np.ndarray] | None:
    """``{episode_index: (T, *state_shape) array}`` in the recorded dtype, or None if none were recorded."""
    import pyarrow.parquet as pq  # heavy: pyarrow

    path = Path(root) / STATES_PATH
    if not path.is_file():
        return None
    try:
        with pq.ParquetFile(path) as f:  # one small file: no dataset API, no thread pool
            table = f.read(use_threads=False)
        meta = json.loads((table.schema.metadata or {}).get(b"hub_envs", b"{}"))
        shape = tuple(int(d) for d in meta.get("shape", []))
        dtype = np.dtype(meta.get("dtype", "float64"))
        episode = table.column("episode_index").to_numpy()
        frame = table.column("frame_index").to_numpy()
        width = int(np.prod(shape)) if shape else 1
        flat = table.column("state").combine_chunks().flatten().to_numpy(zero_copy_only=False)
        flat = flat.reshape(len(episode), width)
    except (OSError, ValueError, KeyError) as exc:
        raise DatasetError(f"Cannot read the recorded env states {path}: {exc}. Re-publish the env with push_env.") from exc
    out: dict[int, np.ndarray] = {}
    order = np.lexsort((frame, episode))
    episode, frame, flat = episode[order], frame[order], flat[order]
    bounds = np.flatnonzero(np.diff(episode)) + 1
    for idx in np.split(np.arange(len(episode)), bounds):
        if not len(idx):
            continue
        ep = int(episode[idx[0]])
        if not np.array_equal(frame[idx], np.arange(len(idx))):
            raise DatasetError(f"{path}: the frames of episode {ep} are not 0..{len(idx) - 1}. Re-publish the env with push_env.")
        out[ep] = flat[idx].reshape(len(idx), *shape).astype(dtype, copy=False)
    return out
