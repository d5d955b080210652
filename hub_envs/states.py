"""Simulator states recorded beside a dataset: ``env.get_state()`` before every action.

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

The state shape and dtype are in the schema metadata (key ``hub_envs``). Written with fixed
parquet options, so the same states give the same bytes.

Example:
    >>> import tempfile, numpy as np
    >>> from hub_envs.states import read_env_states, write_env_states
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

import numpy as np

from hub_envs.errors import DatasetError

__all__ = ["STATES_PATH", "write_env_states", "read_env_states", "has_env_states"]

STATES_PATH = "meta/env_states.parquet"
_PARQUET_OPTS = dict(compression="snappy", use_dictionary=False, write_statistics=False, version="2.6")


def _as_state_array(states) -> np.ndarray | None:
    if states is None:
        return None
    arr = np.asarray(states)
    if arr.ndim < 1 or arr.dtype.kind not in "fiub":
        return None
    return arr


def write_env_states(root: str | os.PathLike, states: Mapping[int, np.ndarray | None]) -> bool:
    """Write ``{episode_index: (T, *state_shape) array}`` to ``root/meta/env_states.parquet``.

    Returns False (and writes nothing) when any episode has no states or the states are not numeric
    arrays of one shape: states are all-or-nothing, a replay must be able to rely on them.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {int(k): _as_state_array(v) for k, v in states.items()}
    if not arrays or any(a is None for a in arrays.values()):
        return False
    shapes = {a.shape[1:] for a in arrays.values()}
    if len(shapes) != 1:
        return False
    shape = shapes.pop()
    width = int(np.prod(shape)) if shape else 1
    order = sorted(arrays)
    flat = np.concatenate([arrays[i].reshape(len(arrays[i]), width).astype(np.float64) for i in order])
    episode = np.concatenate([np.full(len(arrays[i]), i, dtype=np.int64) for i in order])
    frame = np.concatenate([np.arange(len(arrays[i]), dtype=np.int64) for i in order])
    state_col = pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1), type=pa.float64()), width)
    meta = {
        "shape": list(shape),
        "dtype": str(next(iter(arrays.values())).dtype),
        "source": "env.get_state() before action t (hub-envs)",
    }
    table = pa.table({"episode_index": episode, "frame_index": frame, "state": state_col})
    table = table.replace_schema_metadata({"hub_envs": json.dumps(meta, sort_keys=True)})
    path = Path(root) / STATES_PATH
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path, **_PARQUET_OPTS)
    return True


def has_env_states(root: str | os.PathLike) -> bool:
    return (Path(root) / STATES_PATH).is_file()


def read_env_states(root: str | os.PathLike) -> dict[int, np.ndarray] | None:
    """``{episode_index: (T, *state_shape) array}`` in the recorded dtype, or None if none were recorded."""
    import pyarrow.parquet as pq

    path = Path(root) / STATES_PATH
    if not path.is_file():
        return None
    try:
        table = pq.read_table(path)
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
