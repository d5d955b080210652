"""Observations in shared memory: one sealed ``memfd`` per leaf ``Box`` of an observation space.

The parent makes the buffers and hands their fds to its workers (no name in ``/dev/shm``, nothing for a sandbox
to reach); a worker writes an env's observation into its row, the parent reads it back.

Example:
    >>> import numpy as np
    >>> from gymnasium import spaces
    >>> buffers = ObservationBuffers(box_leaves(spaces.Dict({"pos": spaces.Box(-1, 1, (2,), np.float32)})), 1)
    >>> buffers.write_exact(0, {"pos": np.array([0.5, -0.5], np.float32)}), buffers.read_one()["pos"].tolist()
    (True, [0.5, -0.5])
    >>> buffers.close()
"""

from __future__ import annotations

import mmap
import os
from typing import Any

import numpy as np
from gymnasium import spaces

from hub_envs.isolation.doorbell import sealed_memfd

#: ``[(key path, Box)]``: the leaves of an observation space that travel in shared memory
Leaves = list[tuple[tuple[str, ...], spaces.Box]]


def box_leaves(space: spaces.Space, prefix: tuple[str, ...] = ()) -> Leaves | None:
    """The leaves of an observation space that can travel in shared memory.

    Args:
        space: an observation space.
        prefix: the key path of ``space`` inside the whole space (the recursion's).

    Returns:
        ``[(key path, Box)]`` for a Box or a (nested) Dict of Boxes, in the Dict's key order; None for any other
        space (its observations travel in the answers).
    """
    if isinstance(space, spaces.Box):
        return [(prefix, space)]
    if isinstance(space, spaces.Dict):
        out = []
        for k, sub in space.spaces.items():
            leaves = box_leaves(sub, (*prefix, k))
            if leaves is None:
                return None
            out += leaves
        return out
    return None


def _get(obs: Any, path: tuple[str, ...]) -> Any:
    for k in path:
        obs = obs[k]
    return obs


class ObservationBuffers:
    """Per-leaf shared arrays ``(n, *shape)`` of the leaf's dtype, each in a sealed memfd (a worker can write them,
    never shrink them under the parent's mapping).

    Args:
        leaves: what :func:`box_leaves` gave for the observation space.
        n: rows: the number of envs whose observations they hold.
        fds: the memfds to map, in the order of ``leaves`` (a worker's, from the parent); None makes them (the
            parent, which hands ``self.fds`` to its workers).
    """

    def __init__(self, leaves: Leaves, n: int, fds: list[int] | None = None):
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
        """Write an observation only if reading it back gives exactly it.

        Args:
            index: the env's row.
            obs: the observation: arrays of exactly these dtypes and shapes, dicts of exactly these keys in this order.

        Returns:
            Whether it was written (False: nothing was, it travels in the answer).
        """
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
        """A copy of one env's observation.

        Args:
            index: the env's row.

        Returns:
            An array (a 0-d one stays an array), or dicts of arrays as the space nests them.
        """
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
        """Write an observation of the space's layout (numpy casts what it can, as a ``SyncVectorEnv`` batch does).

        Args:
            index: the env's row.
            obs: the observation.
        """
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
        """Unmap the arrays and close the memfds (again: nothing)."""
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
