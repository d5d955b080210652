"""The page a worker shares with its parent beside their socket (message counters, mail slots for short messages,
a bounded busy-wait before a side sleeps) and the parent's choice of how to wait for each answer
(:class:`WaitChooser`). The design, its memory ordering and what a hostile worker can do with the page:
``docs/isolation.md``.

Example:
    >>> import socket
    >>> from hub_envs.isolation.doorbell import Doorbell, PastDeadline, WORKER
    >>> a, b = socket.socketpair()
    >>> import os
    >>> parent = Doorbell(sock_fd=a.fileno())                  # the parent makes the page and the wake-up pair
    >>> worker = Doorbell(tuple(os.dup(fd) for fd in parent.fds_for_worker()), sock_fd=b.fileno(), side=WORKER)
    >>> parent.mail = True
    >>> parent.send(b"step 1", a.sendall)                      # short: through the page (on x86-64)
    >>> worker.receive(None, 0.0, lambda deadline: b.recv(64))
    b'step 1'
    >>> worker.send(b"done", b.sendall)                        # answered in kind
    >>> parent.receive(0.0, 0.0, lambda deadline: a.recv(64))
    b'done'
    >>> try:
    ...     parent.receive(0.0, 0.0, lambda deadline: a.recv(64))  # nothing more came by the deadline
    ... except PastDeadline:
    ...     print("past the deadline")
    past the deadline
    >>> worker.close(); parent.close(); a.close(); b.close()
"""

from __future__ import annotations

import collections
import math
import mmap
import os
import platform
import select
import socket
import statistics
import threading
import time
from collections.abc import Callable
from typing import Any

#: the counters' slots (int64 indices, 128 bytes apart so that each has its cache line): what the parent sent,
#: what the worker sent. The slot after a counter holds the length of the message in that side's mail slot (-1:
#: the message is in the socket)
REQUEST, REPLY = 0, 16
#: the slot of the flag "the receiver of these messages is asleep" (the worker for requests, the parent for replies)
_ASLEEP = {REQUEST: 32, REPLY: 48}
#: the longest message that travels in the page; longer ones go through the socket
MAIL_BYTES = 32768
_BODY = {REQUEST: 512, REPLY: 512 + MAIL_BYTES}
_SIZE = 512 + 2 * MAIL_BYTES
#: which end a :class:`Doorbell` is (the parent receives replies, the worker requests)
PARENT, WORKER = "parent", "worker"
#: the mail slots need stores seen in program order (x86-64's TSO; see the module docstring)
MAIL = platform.machine().lower() in ("x86_64", "amd64")
#: in a fast step request's CPU field (:data:`~hub_envs.isolation.protocol.FAST_HEADER`): the parent busy-waits
#: for this answer (and is pinned nowhere); the worker then busy-waits for the next request
SPINNING = -2
#: the longest a side busy-waits for the other before it sleeps
MAX_SPIN_S = 0.0005
#: False: never spin and never use the mail slots (both sides sleep in the socket); read at every message
enabled = True


class PastDeadline(Exception):
    """No message (or not a whole one) came by the deadline."""


class Oversized(Exception):
    """The other side announced a message longer than it may send (``args``: the length announced, the limit)."""


def sealed_memfd(name: str, size: int) -> int:
    """A memfd whose size nobody can change any more (``F_SEAL_SHRINK|GROW|SEAL``): a process it is handed to can
    write its bytes but never truncate it under another's mapping (the reader would get a SIGBUS).

    Args:
        name: the memfd's name (``/proc/<pid>/fd`` shows it as ``/memfd:<name>``).
        size: its size in bytes.

    Returns:
        The file descriptor (close-on-exec; hand it on with ``pass_fds`` or ``SCM_RIGHTS``).

    Raises:
        OSError: the kernel refused (no memfd or no sealing: not Linux, or too old).

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


def available_cpus(cgroup: str = "/sys/fs/cgroup") -> int:
    """The CPUs this process may run on: its affinity, capped by a cgroup CPU quota (a container started with
    ``--cpus=2`` on a 64-CPU host has 64 in its affinity and 2 CPUs of time: busy-waiting on 63 would burn it).

    Args:
        cgroup: where the cgroup file system is mounted.

    Returns:
        At least 1.

    >>> import pathlib, tempfile
    >>> root = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (root / "cpu.max").write_text("150000 100000")
    >>> available_cpus(str(root)) <= 2
    True
    """
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        cpus = os.cpu_count() or 1
    quota = _cgroup_quota(cgroup)
    return max(1, min(cpus, math.ceil(quota))) if quota else cpus


def _cgroup_quota(root: str) -> float | None:
    """CPUs' worth of time the cgroup grants (v2 ``cpu.max``, else v1 ``cpu.cfs_quota_us`` / ``cfs_period_us``),
    None without a quota."""
    try:
        with open(os.path.join(root, "cpu.max")) as f:
            quota, period = f.read().split()[:2]
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        pass
    try:
        with open(os.path.join(root, "cpu", "cpu.cfs_quota_us")) as f:
            quota_us = int(f.read())
        with open(os.path.join(root, "cpu", "cpu.cfs_period_us")) as f:
            period_us = int(f.read())
        return None if quota_us <= 0 or period_us <= 0 else quota_us / period_us
    except (OSError, ValueError):
        return None


class Doorbell:
    """One end of the shared page: :meth:`send` a message, :meth:`receive` one. ``mail`` (attribute): whether
    :meth:`send` may use the mail slot (the worker answers in kind whatever this says).

    Args:
        fds: the page and the worker's end of the wake-up socketpair, from the parent's :meth:`fds_for_worker`
            (the worker); None makes them (the parent).
        sock_fd: the message socket beside the page (polled while asleep).
        side: :data:`PARENT` (receives replies) or :data:`WORKER` (receives requests).

    Raises:
        OSError: the page or the wake-up socketpair could not be made (nothing is left open).
    """

    def __init__(self, fds: tuple[int, int] | None = None, *, sock_fd: int, side: str = PARENT):
        owned: list = []
        try:
            if fds is None:
                page = sealed_memfd("hub-envs-doorbell", _SIZE)
                owned.append(page)
                mine, theirs = socket.socketpair()
                owned += [mine, theirs]
                self._theirs: socket.socket | None = theirs
            else:
                page, self._theirs = fds[0], None
                mine = socket.socket(fileno=fds[1])
                owned += [page, mine]
            self._page, self._wake_sock = page, mine
            self.side = side
            self.inbox, self.outbox = (REPLY, REQUEST) if side == PARENT else (REQUEST, REPLY)
            self._map = mmap.mmap(page, _SIZE)
            owned.append(self._map)
            self._slots = memoryview(self._map).cast("q")
            self._poller = select.poll()
            self._poller.register(sock_fd, select.POLLIN)
            self._poller.register(mine.fileno(), select.POLLIN)
        except BaseException:
            for handle in owned:
                handle.close() if not isinstance(handle, int) else os.close(handle)
            raise
        self._lock = threading.Lock()
        self.mail = False
        self._mailed_in = False  # whether the last message received came through the page
        self.rung = 0  # messages sent
        self.heard = 0  # messages received
        self._sock_fd = sock_fd
        self._closed = False

    def fds_for_worker(self) -> tuple[int, int]:
        """The fds to hand to the worker (``pass_fds``), in the order its :class:`Doorbell` takes them."""
        assert self._theirs is not None, "only the parent's end has the worker's fds"
        return self._page, self._theirs.fileno()

    def _fence(self) -> None:
        # a full memory barrier: a lock's acquire and release are atomic read-modify-writes (lock cmpxchg)
        lock = self._lock
        if lock.acquire(False):
            lock.release()
        else:  # held: a KeyboardInterrupt came between the two calls once; a fresh lock, never a deadlock
            self._lock = threading.Lock()
            self._fence()

    def send(self, data: bytes, send_socket: Callable[[bytes], object]) -> None:
        """Send one message: into the mail slot when it fits and mail is on (the worker: when the message it
        answers came that way), else through the socket.

        Args:
            data: the message.
            send_socket: sends a message through the socket (called after the counter moved, so a receiver woken
                by the socket always sees it).
        """
        slots, box = self._slots, self.outbox
        mail = (self._mailed_in if self.side == WORKER else self.mail) and enabled and MAIL
        if mail and len(data) <= MAIL_BYTES:
            start = _BODY[box]
            self._map[start : start + len(data)] = data
            slots[box + 1] = len(data)
            self.rung += 1
            slots[box] = self.rung
            self._fence()  # the counter is visible before the flag is read (the receiver fences the other way)
            if slots[_ASLEEP[box]]:
                try:
                    self._wake_sock.send(b"\0", socket.MSG_DONTWAIT)
                except OSError:  # a full buffer: the receiver is woken anyway (or gone)
                    pass
        else:
            slots[box + 1] = -1
            self.rung += 1
            slots[box] = self.rung
            send_socket(data)

    def receive(
        self,
        deadline: float | None,
        spin_until: float,
        read_socket: Callable[[float | None], bytes],
        on_sleep: Callable[[], object] | None = None,
    ) -> bytes:
        """The next message: busy-wait a while, then sleep until it comes or the deadline passes.

        Args:
            deadline: a ``time.perf_counter()`` value to wait until (None: for good).
            spin_until: a ``time.perf_counter()`` value to busy-wait until before sleeping (0: sleep at once).
            read_socket: reads one message from the socket by a deadline: one whose length slot says -1, or bytes
                that came without a counter (not a message hub-envs sends: read so that the caller finds out, as
                the other end closing).
            on_sleep: runs before each sleep.

        Returns:
            The message (a copy: the sender may write the page again).

        Raises:
            PastDeadline: nothing came by the deadline.
            Oversized: the other side announced a message longer than :data:`MAIL_BYTES` in the page.
        """
        slots, box, clock = self._slots, self.inbox, time.perf_counter
        heard = self.heard
        while slots[box] <= heard and clock() < spin_until:
            pass
        while True:
            if slots[box] > heard:
                self.heard = heard + 1
                size = slots[box + 1]
                self._mailed_in = size >= 0
                if size < 0:
                    return read_socket(deadline)
                if size > MAIL_BYTES:
                    raise Oversized(size, MAIL_BYTES)
                start = _BODY[box]
                return self._map[start : start + size]  # a copy: the sender may write the page again
            asleep = _ASLEEP[box]
            slots[asleep] = 1
            self._fence()  # the flag is visible before the counter is read again (the sender fences the other way)
            if slots[box] > heard:
                slots[asleep] = 0
                continue
            if on_sleep is not None:
                on_sleep()
            wait = None if deadline is None else max(0, math.ceil((deadline - clock()) * 1000))
            try:
                ready = self._poller.poll(wait)
            finally:
                slots[asleep] = 0
            sock_ready = False
            for fd, _ in ready:
                if fd == self._sock_fd:
                    sock_ready = True
                else:  # woken: take what the wake-up socket holds (one byte a ring), never blocking, whatever the
                    # other end did (more than this read leaves the next poll ready at once: a wake-up for nothing)
                    try:
                        self._wake_sock.recv(4096, socket.MSG_DONTWAIT)
                    except OSError:
                        pass
            if slots[box] > heard:  # a message, even if it came just as the deadline passed
                continue
            if sock_ready:  # bytes without a counter, or the other end closed
                self._mailed_in = False
                return read_socket(deadline)
            if not ready or (deadline is not None and clock() >= deadline):  # woken for nothing, past the deadline
                raise PastDeadline

    def close(self) -> None:
        """Unmap the page and close its fds (again: nothing)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._slots.release()
            self._map.close()
        finally:
            for handle in (self._wake_sock, self._theirs):
                if handle is not None:
                    handle.close()
            try:
                os.close(self._page)
            except OSError:
                pass


class SpinBudget:
    """How long to busy-wait next: twice the usual wait plus 20 us, at most :data:`MAX_SPIN_S`; zero when the
    usual wait is longer, when spinning is off or on a single CPU.

    Args:
        active: whether this side busy-waits at all.
        cpus: the CPUs to count on (default :func:`available_cpus`).

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
        self.active = active and (available_cpus() if cpus is None else cpus) > 1
        self.usual = 0.0

    def seconds(self) -> float:
        if not (self.active and enabled) or self.usual > MAX_SPIN_S:
            return 0.0
        return min(MAX_SPIN_S, 2 * self.usual + 20e-6)

    def observe(self, waited: float) -> None:
        """Count a wait that just ended into the usual wait.

        Args:
            waited: its seconds (clipped, so one long pause does not stop spinning for long).
        """
        self.usual += self.ALPHA * (min(waited, 4 * MAX_SPIN_S) - self.usual)


#: how a parent waits for an answer (:class:`WaitChooser`): both sides busy-wait; it sleeps and the worker sleeps on
#: its CPU (:mod:`~hub_envs.isolation.affinity`); both sleep wherever the scheduler puts them
SPIN, PIN, SLEEP = "spin", "pin", "sleep"


class WaitChooser:
    """The parent's choice, step by step, of how to wait for the worker: the way whose steps took least time lately.

    Busy-waiting is fastest where each side has a CPU to itself, and the slowest of all where they must share one
    with other work (a spinning side takes the CPU the other needs); sleeping on the parent's CPU makes wake-ups
    cheap on a machine whose idle CPUs halt, and costs migrations where that CPU is busy. Which way wins depends on
    the machine and its load at the time, so the chooser measures each way's cycle (one step's request to the
    next's: what waiting that way cost the caller, the worker's work and the caller's own included) and uses the way
    whose last cycles (at most :attr:`KEPT`) took least on average. Every other way is tried for :attr:`TRY` steps now and
    then: after :attr:`FIRST` steps, then twice as long after each try it lost, at most :attr:`LAST` (a try ends
    early when it is clearly losing), and soon when the way in use got slower than another way was when last tried
    (the machine got busy).

    Args:
        ways: the ways that may be chosen, in order of preference while nothing is known yet.

    >>> chooser = WaitChooser((SPIN, SLEEP))
    >>> chooser.next(0.0)
    'spin'
    >>> t = 0.0
    >>> for _ in range(500):                  # spinning takes 400 us a step, sleeping 150 us (a busy machine)
    ...     way = chooser.next(t)
    ...     t += 400e-6 if way == SPIN else 150e-6
    >>> chooser.way, round(chooser.usual[SLEEP] * 1e6)   # the way in use (the other one is still tried now and then)
    ('sleep', 150)
    """

    #: steps of a try of another way, and how many of its first ones are not counted (the other side is still
    #: waiting the old way)
    TRY, SETTLE = 12, 2
    FIRST, LAST = 64, 4096
    #: cycles kept per way (their mean is the way's usual cycle; one over :attr:`OUTLIER` times their median is left
    #: out: the caller paused, or did something else between two steps)
    KEPT, OUTLIER = 32, 10.0
    #: how much cheaper another way must be to be chosen (noise must not flip the choice back and forth), and how
    #: much slower a try must be to end early, lost
    MARGIN, LOSING = 0.9, 2.0

    def __init__(self, ways: tuple[str, ...]):
        self.ways = tuple(ways)
        self.way = self.ways[0]
        self._cycles: dict[str, collections.deque] = {way: collections.deque(maxlen=self.KEPT) for way in self.ways}
        self._steps = 0
        self._last: tuple[str, float] | None = None  # the way and the start of the step before this one
        self._trying: str | None = None
        self._tried: list[float] = []  # the counted cycles of the current try
        self._try_steps = 0
        self._gap = dict.fromkeys(self.ways, self.FIRST)
        self._next_try = {way: self.FIRST // 4 * (i + 1) for i, way in enumerate(self.ways)}  # each tried early once
        self._next_check = self.FIRST

    @property
    def usual(self) -> dict[str, float | None]:
        """Each way's usual cycle in seconds (the mean of its last cycles; None: never measured)."""
        return {way: self._mean(c) if c else None for way, c in self._cycles.items()}

    @classmethod
    def _mean(cls, cycles: Any) -> float:
        top = cls.OUTLIER * statistics.median(cycles)
        kept = [c for c in cycles if c <= top]
        return sum(kept) / len(kept)

    def next(self, now: float, allowed: tuple[str, ...] | None = None) -> str:
        """The way to wait for the answer to the step starting now; counts the step before it.

        Args:
            now: the ``time.perf_counter()`` at which this step's request is sent.
            allowed: the ways possible for this step (default all); one that is not is skipped.

        Returns:
            :data:`SPIN`, :data:`PIN` or :data:`SLEEP`.
        """
        if self._last is not None:
            way, started = self._last
            if self._trying != way or self._try_steps > self.SETTLE:
                self._cycles[way].append(now - started)
                if self._trying == way:
                    self._tried.append(now - started)
        self._steps += 1
        way = self._choose(self.ways if allowed is None else allowed)
        self._last = (way, now)
        return way

    def forget_last(self) -> None:
        """The step that was just waited for says nothing of its way (something else ran before the next step)."""
        self._last = None

    def _choose(self, allowed: tuple[str, ...]) -> str:
        if self._trying is not None:
            if self._trying in allowed and self._try_steps < self.TRY and not self._losing():
                self._try_steps += 1
                return self._trying
            self._end_try()
        if self._steps >= self._next_check:
            self._check()
        ways = [way for way in self.ways if way in allowed]
        if not ways:
            return SLEEP
        for way in ways:  # a way whose turn to be tried came
            if way != self.way and self._steps >= self._next_try[way]:
                self._trying, self._tried, self._try_steps = way, [], 1
                return way
        if self.way not in ways:  # the way in use is not possible now: the best of the others
            usual = self.usual
            return min(ways, key=lambda w: (usual[w] is None, usual[w] or 0.0))
        return self.way

    def _end_try(self) -> None:
        way, tried, self._trying = self._trying, self._tried, None
        current = self._cycles[self.way]
        if tried and (not current or self._mean(tried) < self.MARGIN * self._mean(current)):
            self._gap[self.way] = self.FIRST  # the way it replaces may win again soon: tried again early
            self._next_try[self.way] = self._steps + self.FIRST
            self.way, self._gap[way] = way, self.FIRST
        else:
            self._gap[way] = min(2 * self._gap[way], self.LAST)
        self._next_try[way] = self._steps + self._gap[way]

    def _losing(self) -> bool:
        """Whether the try so far is so much slower than the way in use that more of it would only cost."""
        current = self._cycles[self.way]
        return len(self._tried) >= 2 and bool(current) and min(self._tried) > self.LOSING * self._mean(current)

    def _check(self) -> None:
        """Every :attr:`FIRST` steps: is the way in use now slower than another way was when last tried? Then that
        one is tried soon."""
        self._next_check = self._steps + self.FIRST
        usual = self.usual
        if usual[self.way] is None:
            return
        for way in self.ways:
            if way != self.way and usual[way] is not None and self.MARGIN * usual[self.way] > usual[way]:
                self._gap[way], self._next_try[way] = self.FIRST, min(self._next_try[way], self._steps)
