"""Where a side that sleeps waits for the other: on the CPU of the thread that will wake it, where waking it is cheap.

The parent pins its waiting thread (:func:`pin_here` / :func:`unpin`); the worker sleeps on the parent's CPU and
runs the env on its own CPU set (:class:`Follower`). A placement hint, never a condition (``docs/isolation.md``).

Example:
    >>> import os
    >>> from hub_envs.isolation.affinity import pin_here, unpin
    >>> cpu, saved = pin_here()
    >>> cpu >= 0 and os.sched_getaffinity(0) == {cpu}
    True
    >>> unpin(saved); os.sched_getaffinity(0) == saved
    True
"""

from __future__ import annotations

import os

NO_CPU = -1
#: False: never pin (the scheduler places parent and workers as it likes); read at every call
enabled = True


def _getcpu():
    try:
        import ctypes

        fn = ctypes.CDLL(None, use_errno=True).sched_getcpu
        fn.restype = ctypes.c_int
        fn.argtypes = []
        if fn() < 0 or not hasattr(os, "sched_setaffinity"):
            return None
        return fn
    except (OSError, AttributeError):  # pragma: no cover - not glibc / not Linux
        return None


_GETCPU = _getcpu()


def pin_here() -> tuple[int, set[int] | None]:
    """Pin the calling thread to the CPU it runs on, while it sleeps waiting for a worker.

    Returns:
        ``(cpu, the CPU set to give back to unpin)``, or ``(NO_CPU, None)`` where nothing was pinned (off, not
        Linux, a single CPU).
    """
    if _GETCPU is None or not enabled:
        return NO_CPU, None
    cpu = _GETCPU()
    try:
        saved = os.sched_getaffinity(0)
        if cpu not in saved:  # pragma: no cover - moved between the two calls
            return NO_CPU, None
        if len(saved) > 1:
            os.sched_setaffinity(0, (cpu,))
    except OSError:  # pragma: no cover
        return NO_CPU, None
    return cpu, saved


def unpin(saved: set[int] | None) -> None:
    """Give the calling thread back its CPU set.

    Args:
        saved: what :func:`pin_here` returned second (None: nothing was pinned, nothing to do).
    """
    if saved is not None and len(saved) > 1:
        try:
            os.sched_setaffinity(0, saved)
        except OSError:  # pragma: no cover
            pass


class Follower:
    """The worker's side: sleep on the parent's CPU, run the env on the worker's own CPU set (read when made)."""

    def __init__(self) -> None:
        try:
            self.own: set[int] | None = os.sched_getaffinity(0)
        except (AttributeError, OSError):  # pragma: no cover - not Linux
            self.own = None
        self.pinned = False

    def wait_on(self, cpu: int) -> None:
        """Before blocking for the next request: sleep on the parent's CPU if it is one of the worker's.

        Args:
            cpu: the CPU the parent waits on (from the request), or a negative value: none.
        """
        own = self.own
        if own is None or len(own) < 2 or cpu not in own:
            return
        try:
            os.sched_setaffinity(0, (cpu,))
            self.pinned = True
        except OSError:  # pragma: no cover - e.g. a cpuset changed under us: stop trying
            self.own = None

    def woken(self) -> None:
        """Right after a request arrived: back to the worker's own CPU set."""
        if self.pinned:
            self.pinned = False
            try:
                os.sched_setaffinity(0, self.own)
            except OSError:  # pragma: no cover
                self.own = None
