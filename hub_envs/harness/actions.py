"""Action spaces as hub-envs records them, and how recorded actions go back to an env.

================================  ====================  ======================================
the env's action space            stored (dataset)      declared shape the config may give
================================  ====================  ======================================
``Box`` of floats                 float32, its shape    its shape
``Box`` of integers               int64, its shape      its shape
``Discrete(n)``                   int64, ``(1,)``       ``()`` or ``(1,)`` (LeRobot's scalar)
``MultiDiscrete`` / ``MultiBinary``  int64, its shape   its shape
anything else (``Text``, ``Graph``, ``Dict``/``Tuple`` actions, ...)   refused at push, named
================================  ====================  ======================================

Example:
    >>> from gymnasium import spaces
    >>> stored_action(spaces.Discrete(2)), stored_action(spaces.Box(-1, 1, (3,)))
    (((1,), 'int64'), ((3,), 'float32'))
    >>> accepts_declared(spaces.Discrete(2), ()), accepts_declared(spaces.Discrete(2), (1,))
    (True, True)
    >>> unsupported_reason(spaces.Text(5))
    'Text(1, 5, charset=...) actions are not supported: use a Box (continuous) or Discrete / MultiDiscrete (integer) action space'
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

__all__ = ["stored_action", "accepts_declared", "unsupported_reason", "to_env_actions", "IntegerActions"]


def unsupported_reason(space: Any) -> str | None:
    """Why hub-envs cannot record actions of a space.

    Args:
        space: an action space.

    Returns:
        The reason, or None when it can (Box of numbers, Discrete, MultiDiscrete, MultiBinary).
    """
    if isinstance(space, (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)):
        return None
    if isinstance(space, spaces.Box) and (np.issubdtype(space.dtype, np.floating) or np.issubdtype(space.dtype, np.integer)):
        return None
    text = repr(space)
    if isinstance(space, spaces.Text):
        text = f"Text({space.min_length}, {space.max_length}, charset=...)"
    return f"{text} actions are not supported: use a Box (continuous) or Discrete / MultiDiscrete (integer) action space"


def _integer(space: Any) -> bool:
    return not isinstance(space, spaces.Box) or np.issubdtype(space.dtype, np.integer)


def stored_action(space: Any) -> tuple[tuple[int, ...], str]:
    """How the dataset's ``action`` column stores actions of a supported space.

    Args:
        space: an action space.

    Returns:
        ``(shape, dtype)``: a Discrete's scalar as ``(1,)``, integers as ``int64``, floats as ``float32``.
    """
    shape = tuple(int(d) for d in (space.shape or ()))
    return (shape or (1,)), ("int64" if _integer(space) else "float32")


def accepts_declared(space: Any, declared: tuple[int, ...]) -> bool:
    """Whether a config may declare ``declared`` as the action shape of ``space`` (a Discrete: ``()`` or ``(1,)``).

    Args:
        space: the env's action space.
        declared: the shape the config declares.

    Returns:
        True when it may.
    """
    shape = tuple(space.shape or ())
    return declared == shape or (shape == () and declared in ((), (1,)))


def to_env_actions(actions: np.ndarray, space: Any) -> np.ndarray:
    """Recorded actions back in the env's own layout and dtype (a Discrete's scalar per step).

    Args:
        actions: ``(T, *stored shape)``.
        space: the env's action space.

    Returns:
        ``(T, *space.shape)`` of the space's dtype (integers rounded from floats).
    """
    shape = tuple(space.shape or ())
    dtype = getattr(space, "dtype", None)
    if actions.shape[1:] != shape and int(np.prod(actions.shape[1:])) == int(np.prod(shape)):
        actions = actions.reshape(len(actions), *shape)
    if dtype is not None and actions.dtype != dtype:
        actions = np.rint(actions).astype(dtype) if _integer(space) and actions.dtype.kind == "f" else actions.astype(dtype)
    return actions


class IntegerActions(gym.ActionWrapper):
    """Hands an env with integer actions (``Discrete``, ``MultiDiscrete``) what it expects when a policy gives
    floats in LeRobot's layout (``Discrete``: shape ``(1,)``), as LeRobot's eval loop does; other actions pass."""

    def action(self, action: Any) -> Any:
        """An action in the env's integer form.

        Args:
            action: what the policy gave (floats for an integer space are rounded).

        Returns:
            A Discrete's scalar, or an integer array of the space's shape.
        """
        arr = np.asarray(action)
        if isinstance(self.env.action_space, spaces.Discrete):
            return np.int64(np.rint(arr.reshape(-1)[0])) if arr.size == 1 else action
        if arr.dtype.kind == "f":
            return np.rint(arr).astype(self.env.action_space.dtype).reshape(self.env.action_space.shape)
        return action
