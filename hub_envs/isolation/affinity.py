"""Keeping a worker on the CPU of the thread that waits for it, where waking it is cheap.

A step through a worker process is two wake-ups: the parent wakes the worker, the worker wakes the parent.
Linux puts a woken task on an idle CPU when there is one, and waking an idle CPU costs far more than the
rest of the round trip on a virtual machine whose idle CPUs halt (measured on the project's 2-CPU VM: a
round trip between two processes on one CPU 7-14 us, on two CPUs 100-130 us). A single env's parent and worker
first busy-wait a moment, talking through a shared page (:mod:`~hub_envs.isolation.doorbell`; then nothing is pinned); when they sleep, the fix is
where they sleep:

* the parent (:func:`pin_here` / :func:`unpin`) pins the *calling thread* to the CPU it is on while it
  waits for the answer, and puts that CPU in the request; its own CPU set is restored as soon as it is
  woken (other threads of the process are never touched);
* the worker (:class:`Follower`) pins itself to that CPU only while it waits for the next request and
  goes back to its own CPU set the moment it is woken, so the env's code (and any thread it starts) runs
  with the worker's full CPU set.

Where a CPU cannot be read or pinned (not Linux, a CPU outside the allowed set), nothing is pinned and the
call goes on as before: this is a placement hint, never a condition. ``affinity.enabled = False`` turns it
off for the process (the benchmark measures both).

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


def current_cpu() -> int:
    """The CPU the calling thread runs on, or ``NO_CPU`` (-1) where that cannot be known."""
    return _GETCPU() if _GETCPU is not None else NO_CPU


def pin_here() -> tuple[int, set[int] | None]:
    """Pin the calling thread to its current CPU: ``(cpu, CPU set to give back to unpin)``, or ``(NO_CPU, None)``."""
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
    """Give the calling thread back the CPU set :func:`pin_here` returned."""
    if saved is not None and len(saved) > 1:
        try:
            os.sched_setaffinity(0, saved)
        except OSError:  # pragma: no cover
            pass


class Follower:
    """The worker's side: sleep on the parent's CPU, run on the worker's own CPU set."""

    def __init__(self) -> None:
        try:
            self.own: set[int] | None = os.sched_getaffinity(0)
        except (AttributeError, OSError):  # pragma: no cover - not Linux
            self.own = None
        self.pinned = False

    def wait_on(self, cpu: int) -> None:
        """Before blocking for the next request: sleep on ``cpu`` (the parent's) if it is one of ours."""
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
