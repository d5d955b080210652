"""A doorbell beside a worker's socket: the waiting side busy-waits on a shared counter for a short, adaptive
while before it sleeps in the socket.

A step through a worker process is two wake-ups, and a wake-up is what a round trip costs: on the project's
2-CPU VM a task sleeping in a socket takes ~100 us to be woken on an idle CPU (see
:mod:`~hub_envs.isolation.affinity` for the other fix, used when nothing spins), and busy-waiting in the
socket itself (``poll(0)`` in a loop) costs the env's step ~15-25% in caches the kernel entries evict. So
both sides keep their messages in the socket and, in a small shared page (a ``memfd``, one per worker), a
counter of the messages each has sent: a waiting side reads the other's counter in a loop (no system call)
until it moves, then reads the message from the socket. Measured with hover (``benchmarks/bench_isolation``):
a step through a worker took 1.9x the in-process step while both sides slept, ~1.4x with the busy-wait.

**The socket stays the only channel for data.** The bell is a hint when to read it: a counter seen before the
message (weakly ordered memory) only makes the reader block in ``recv`` a moment; a worker writing nonsense into
the page only makes the parent stop spinning early or spin until its budget ends. Nothing is ever read from
the page but the one integer, and nothing read from it is acted on but "stop spinning". The page is sealed
(:func:`sealed_memfd`: its size cannot change), so a worker cannot shrink it under the parent's mapping
(reading past the end of a shrunk file is a SIGBUS).

**Spinning costs a CPU, so it is bounded and adaptive** (:class:`SpinBudget`): each side keeps a moving average
of how long it waited for the other and spins for at most twice that (plus 20 us), never more than
:data:`MAX_SPIN_S`, and not at all when the usual wait is longer than that (a wake-up costs well under a
fifth of such a wait) or when the process may run on one CPU only. Only single envs spin; the workers of a
vector env sleep (they share the CPUs with each other). The worker busy-waits only after a step whose parent
busy-waited (a flag in the request). ``doorbell.enabled = False`` turns spinning off for the process, on both
sides (the benchmark measures both). The parent's busy-wait holds the GIL (a Python loop): another thread of
the parent waits at most :data:`MAX_SPIN_S` for it.

Example:
    >>> import os
    >>> from hub_envs.isolation.doorbell import REPLY, Doorbell
    >>> bell = Doorbell()                        # the parent makes it; the worker maps its copy of the fd
    >>> other_side = Doorbell(os.dup(bell.fd))
    >>> bell.wait(REPLY, deadline=0.0)           # nothing sent: the deadline passed
    False
    >>> other_side.ring(REPLY); bell.wait(REPLY, deadline=0.0)
    True
    >>> bell.heard(REPLY); bell.wait(REPLY, deadline=0.0)   # that message was read: waiting again
    False
    >>> other_side.close(); bell.close()
"""

from __future__ import annotations

import mmap
import os
import time

#: the counters' slots (int64 indices, 128 bytes apart so that each has its cache line): what the parent sent,
#: what the worker sent
REQUEST, REPLY = 0, 16
_SIZE = 256
#: in a fast step request's CPU field (:data:`~hub_envs.isolation.protocol.FAST_HEADER`): the parent busy-waits
#: for this answer (and is pinned nowhere); the worker then busy-waits for the next request
SPINNING = -2
#: the longest a side busy-waits for the other before it sleeps in the socket
MAX_SPIN_S = 0.0005
#: False: never spin (both sides sleep in the socket); read at every wait
enabled = True


def sealed_memfd(name: str, size: int) -> int:
    """A memfd of ``size`` bytes whose size nobody can change any more (``F_SEAL_SHRINK|GROW|SEAL``): a
    process it is handed to can write its bytes but never truncate it under another's mapping.

    >>> import os
    >>> fd = sealed_memfd("example", 4096)
    >>> os.ftruncate(fd, 0)
    Traceback (most recent call last):
    PermissionError: [Errno 1] Operation not permitted
    >>> os.close(fd)
    """
    import fcntl

    fd = os.memfd_create(name, os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    try:
        os.ftruncate(fd, size)
        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class Doorbell:
    """Two message counters in a shared page: :meth:`ring` after sending, :meth:`wait` before receiving."""

    def __init__(self, fd: int | None = None):
        if fd is None:
            fd = sealed_memfd("hub-envs-doorbell", _SIZE)
        self.fd = fd
        self._map = mmap.mmap(fd, _SIZE)
        self._slots = memoryview(self._map).cast("q")
        self._rung = {REQUEST: 0, REPLY: 0}
        self._heard = {REQUEST: 0, REPLY: 0}

    def ring(self, slot: int) -> None:
        """One more message sent on ``slot`` (call it after the message is in the socket)."""
        self._rung[slot] += 1
        self._slots[slot] = self._rung[slot]

    def heard(self, slot: int) -> None:
        """One more message of ``slot`` read from the socket (call it for every message, spun for or not)."""
        self._heard[slot] += 1

    def wait(self, slot: int, deadline: float) -> bool:
        """Busy-wait until the other side rang for a message not yet heard (True) or ``deadline`` (a
        ``time.perf_counter()`` value) passed (False: sleep in the socket instead)."""
        slots, heard, clock = self._slots, self._heard[slot], time.perf_counter
        while slots[slot] <= heard:
            if clock() >= deadline:
                return False
        return True

    def close(self) -> None:
        """Unmap the page and close its fd (again: nothing)."""
        if self.fd < 0:
            return
        self._slots.release()
        self._map.close()
        os.close(self.fd)
        self.fd = -1


class SpinBudget:
    """How long to busy-wait next (see the module docstring): twice the usual wait plus 20 us, at most
    :data:`MAX_SPIN_S`; zero when the usual wait is longer, when spinning is off or on a single CPU.

    >>> budget = SpinBudget(cpus=2)
    >>> for _ in range(200):
    ...     budget.observe(0.000140)             # a 140 us step
    >>> round(budget.seconds() * 1e6)            # 2 x 140 + 20
    300
    >>> for _ in range(50):
    ...     budget.observe(0.003)                # a 3 ms wait: sleeping costs little in comparison
    >>> budget.seconds()
    0.0
    """

    ALPHA = 0.1

    def __init__(self, active: bool = True, cpus: int | None = None):
        self.active = active and (_cpus() if cpus is None else cpus) > 1
        self.usual = 0.0

    def seconds(self) -> float:
        if not (self.active and enabled) or self.usual > MAX_SPIN_S:
            return 0.0
        return min(MAX_SPIN_S, 2 * self.usual + 20e-6)

    def observe(self, waited: float) -> None:
        """A wait that just ended (clipped, so one long pause does not stop spinning for long)."""
        self.usual += self.ALPHA * (min(waited, 4 * MAX_SPIN_S) - self.usual)
