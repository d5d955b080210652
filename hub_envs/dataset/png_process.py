"""Camera episodes PNG-encoded (and their image stats computed) in a forked helper process, in submission order.

Why a process and not a thread: ``zlib.compress`` releases the GIL for each frame and needs it back after; while the
main thread steps a Python env, a thread waits for the GIL at every frame (up to ``sys.getswitchinterval()``, 5 ms),
so an encode thread overlapped nothing (``benchmarks/bench_datagen.py``, image variant: 67 us/frame with one thread,
68 inline). A process has a GIL of its own.

How: the helper is this process forked (``os.fork``: the code is already imported, nothing to pickle); frames go to it
through reusable memory files (``memfd``: no name, so nothing is left behind however either side ends, and no
``/dev/shm`` size limit), each handed over once on a socket; the PNG bytes and stats come back on the same socket. A
helper that finished its work waits for the next dataset of this process (:func:`release`): forking it and ending it
cost more than encoding a small dataset's frames. It ends when this process ends or forks, when it has had no work for
:data:`IDLE_SECONDS` (it holds a copy of this process's memory as it was when forked), or when this process dies.
Where it cannot run (not Linux), :func:`acquire` returns None and the writer encodes on a thread.

    >>> import numpy as np
    >>> from hub_envs.dataset.codec import decode_png
    >>> encoder = acquire()
    >>> frames = np.arange(2 * 4 * 4 * 3, dtype=np.uint8).reshape(2, 4, 4, 3)
    >>> encoder.submit([frames])
    >>> [(pngs, stats)] = encoder.result()
    >>> release(encoder, ok=True)
    >>> bool((decode_png(pngs[1]) == frames[1]).all()), stats["count"].tolist()
    (True, [2])
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import gc
import mmap
import os
import signal
import sys
import threading
import time
import traceback
import weakref
from collections import deque
from multiprocessing.connection import Connection, Pipe
from multiprocessing.reduction import recv_handle, send_handle
from typing import Any

import numpy as np

from hub_envs.dataset.codec import encode_png
from hub_envs.dataset.stats import image_stats
from hub_envs.errors import DatasetError

__all__ = ["PngProcess", "acquire", "release", "IDLE_SECONDS"]

#: A helper with no work for this long ends itself (the next dataset forks a new one).
IDLE_SECONDS = 30.0
_SLOTS = 2  # episodes in flight: one being encoded, one being written into
_POLL_S = 1.0  # how often a waiting side checks that the other is alive
_KEEP_SLOTS_BYTES = 64 * 2**20  # an idle helper keeps its slots' memory up to this size (a small dataset's frames)
_STALL_S = 120.0  # no answer for this long (plus 1 s per 10 MB of frames) from a live helper: it is stuck
_IDLE: list[PngProcess] = []  # helpers of this process waiting for the next dataset (at most one)
_IDLE_LOCK = threading.Lock()
_ALL: weakref.WeakSet[PngProcess] = weakref.WeakSet()  # every helper object of this process (a fork unmaps their slots)
_ADVICE = "Nothing was written; run again (write_lerobot_dataset(..., encode_in_background=False) encodes in this process)."


class PngProcess:
    """One helper and its frame slots. :meth:`submit` an episode's frame arrays, :meth:`result` takes the oldest
    episode's ``[(pngs, image_stats), ...]`` (one pair per array), :meth:`close` ends it."""

    def __init__(self, pid: int, conn: Connection):
        self.pid, self.conn = pid, conn
        self.owner = os.getpid()  # a process forked from the owner inherits this object, not the helper
        self.maps: list[mmap.mmap | None] = [None] * _SLOTS
        self.in_flight: deque[tuple[int, int]] = deque()  # (slot, bytes), oldest first
        self.next_slot = 0
        self.exitcode: int | None = None
        _ALL.add(self)

    @property
    def full(self) -> bool:
        """Every slot holds an episode not taken back yet: :meth:`result` before the next :meth:`submit`."""
        return len(self.in_flight) == _SLOTS

    def submit(self, arrays: list[np.ndarray]) -> None:
        """Queue one episode: its ``(T, H, W, C)`` uint8 frame arrays (copied into a slot)."""
        if self.full:
            raise DatasetError("PngProcess.submit: every slot is in use; take a result first.")
        specs, size = [], 0
        for arr in arrays:
            if arr.dtype != np.uint8 or arr.ndim != 4:
                raise DatasetError(f"PngProcess.submit takes uint8 (T, H, W, C) frames, got {arr.dtype} {arr.shape}.")
            specs.append((size, tuple(arr.shape)))
            size += arr.nbytes
        slot = self.next_slot
        view = self._slot(slot, size)
        for (offset, shape), arr in zip(specs, arrays):
            np.ndarray(shape, np.uint8, buffer=view, offset=offset)[...] = arr
        self._send(("encode", slot, specs))
        self.next_slot = (slot + 1) % _SLOTS
        self.in_flight.append((slot, size))

    def result(self) -> list[tuple[list[bytes], dict[str, np.ndarray]]]:
        """The oldest submitted episode's ``(pngs, image_stats)`` per array, in the order given."""
        if not self.in_flight:
            raise DatasetError("PngProcess.result: no episode was submitted.")
        stall = _STALL_S + self.in_flight[0][1] / 10e6
        waited = 0.0
        try:
            while not self.conn.poll(_POLL_S):  # a dead helper shows as EOF, or as not alive; a stuck one as silence
                waited += _POLL_S
                if not self.alive():
                    raise EOFError
                if waited >= stall:
                    self.close(wait=False)
                    raise DatasetError(f"The PNG encoding process gave no answer in {stall:.0f} s (it is stuck). {_ADVICE}")
            status, payload = self.conn.recv()
        except (EOFError, OSError) as exc:
            self.close(wait=False)
            raise DatasetError(
                f"The PNG encoding process stopped (exit status {self.exitcode}) before returning an episode's frames: "
                f"it was killed or ran out of memory. {_ADVICE}"
            ) from exc
        self.in_flight.popleft()
        if status != "ok":
            raise DatasetError(f"Encoding an episode's frames as PNG failed in the helper process: {payload}. {_ADVICE}")
        return payload

    def alive(self) -> bool:
        """The helper runs (it is reaped when it has ended; its exit status is then :attr:`exitcode`)."""
        if self.exitcode is not None or self.owner != os.getpid():
            return False
        try:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
        except ChildProcessError:  # reaped by someone else (SIGCHLD ignored): its pid may be another process's now
            self.exitcode = -1
            return False
        if pid == 0:
            return True
        self.exitcode = os.waitstatus_to_exitcode(status)
        return False

    def close(self, *, wait: bool = True) -> None:
        """End the helper (``wait``: ask it and give it a few seconds; else kill it) and free the slots."""
        if self.owner == os.getpid():
            if wait and self.alive():
                with contextlib.suppress(OSError):
                    self.conn.send(None)
                deadline = time.monotonic() + 5
                while self.alive() and time.monotonic() < deadline:
                    time.sleep(0.005)
            if self.alive():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.pid, signal.SIGKILL)
                with contextlib.suppress(ChildProcessError):
                    self.exitcode = os.waitstatus_to_exitcode(os.waitpid(self.pid, 0)[1])
        with contextlib.suppress(OSError):
            self.conn.close()
        self._unmap()

    def wake(self) -> bool:
        """Take an idle helper back into use: True when it answered (it no longer counts down to ending itself)."""
        try:
            self.conn.send(("ping",))
            return self.conn.poll(5) and self.conn.recv() == ("pong",)
        except (EOFError, OSError):
            return False

    def sleep(self) -> None:
        """Tell the helper it is idle: it ends itself after :data:`IDLE_SECONDS` without work."""
        self._send(("idle",))

    def drop_slots(self) -> None:
        """Free the slots' memory on both sides (the next :meth:`submit` makes them again)."""
        self._send(("drop",))
        self._unmap()

    def _unmap(self) -> None:
        for slot, mm in enumerate(self.maps):
            if mm is not None:
                with contextlib.suppress(BufferError, ValueError):  # a view still held: the GC unmaps it
                    mm.close()
            self.maps[slot] = None

    def _slot(self, slot: int, size: int) -> mmap.mmap:
        """The slot's mapping, holding at least ``size`` bytes: reused (its pages stay: a copy costs no page faults), or
        a new memory file, its pages reserved (no SIGBUS later when memory is short) and handed to the helper."""
        mm = self.maps[slot]
        if mm is not None and len(mm) >= size:
            return mm
        grown = max(size, int(len(mm) * 1.5) if mm is not None else 0, 1)
        try:
            fd = os.memfd_create("hub-envs-png-slot", os.MFD_CLOEXEC)
        except OSError as exc:  # out of file descriptors
            raise DatasetError(f"Cannot make a memory file for an episode's camera frames: {exc}. {_ADVICE}") from exc
        try:
            try:
                os.ftruncate(fd, grown)
                try:  # the pages now: out of memory is an error here, not a SIGBUS when the frames are copied in
                    os.posix_fallocate(fd, 0, grown)
                except OSError as exc:
                    if exc.errno in (errno.ENOMEM, errno.ENOSPC):
                        raise
                    # not supported here: the pages come on first write
                new = mmap.mmap(fd, grown)
            except OSError as exc:
                raise DatasetError(
                    f"No memory for {grown / 2**20:.0f} MiB of an episode's camera frames ({exc.strerror or exc}). Free "
                    f"memory, or write shorter episodes. {_ADVICE}"
                ) from exc
            self._send(("slot", slot))
            try:
                send_handle(self.conn, fd, self.pid)
            except OSError as exc:
                new.close()
                raise self._gone() from exc
        finally:
            os.close(fd)
        if mm is not None:
            mm.close()
        self.maps[slot] = new
        return new

    def _send(self, message: Any) -> None:
        try:
            self.conn.send(message)
        except OSError as exc:
            raise self._gone() from exc

    def _gone(self) -> DatasetError:
        self.alive()
        return DatasetError(f"The PNG encoding process is gone (exit status {self.exitcode}). {_ADVICE}")


def acquire() -> PngProcess | None:
    """An idle helper of this process, or a new one; None where none can run (the caller encodes itself).

    Returns:
        A :class:`PngProcess` with no episode in flight; give it back with :func:`release`.
    """
    with _IDLE_LOCK:  # held briefly: a thread forking meanwhile gives its child a held lock (reset there, though)
        helper = _IDLE.pop() if _IDLE else None
    if helper is not None:
        try:
            if helper.alive() and helper.wake():
                return helper
        except BaseException:  # Ctrl-C while waking it: it is in use now, so end it rather than lose it
            helper.close(wait=False)
            raise
        helper.close(wait=False)  # ended itself after IDLE_SECONDS (maybe just now), or was killed
    return _start()


def release(helper: PngProcess, *, ok: bool) -> None:
    """Give ``helper`` back: kept for the next dataset when its work ended well (``ok``) and none is kept yet, else
    ended (killed when not ``ok``: an episode may still be in it)."""
    if ok and not helper.in_flight and helper.alive():
        try:
            if sum(len(mm) for mm in helper.maps if mm is not None) > _KEEP_SLOTS_BYTES:
                helper.drop_slots()  # a big dataset's frames: not held in memory while idle
            helper.sleep()
            with _IDLE_LOCK:
                if not _IDLE:
                    _IDLE.append(helper)
                    return
        except DatasetError:  # it ended meanwhile
            pass
    helper.close(wait=ok)


@atexit.register
def _close_idle() -> None:
    """At exit: end this process's idle helpers (they would end on their own, a second later)."""
    with _IDLE_LOCK:
        idle = _IDLE[:]
        _IDLE.clear()
    for helper in idle:
        helper.close()


def _forget_parents_helpers() -> None:
    """In a forked child (a helper too): the parent's helpers, idle or in use, are the parent's to use and end; the
    child unmaps its copies of their slots (so it does not hold their memory for its life) and gets a fresh lock (a
    thread of the parent may have held it at the fork)."""
    global _IDLE_LOCK
    _IDLE_LOCK = threading.Lock()
    _IDLE.clear()
    for helper in list(_ALL):
        helper._unmap()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_parents_helpers)


def _start() -> PngProcess | None:
    """Fork a helper (Linux: ``memfd``); None where it cannot run, or no process can be made now."""
    if not sys.platform.startswith("linux") or not hasattr(os, "memfd_create"):
        return None
    try:
        parent_conn, child_conn = Pipe(duplex=True)  # a socket pair: memory files can be handed over it
    except OSError:  # no file descriptors left: encode in this process
        return None
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:  # no memory or process left to fork: encode in this process
        parent_conn.close()
        child_conn.close()
        return None
    if pid == 0:  # the helper
        code = 1
        try:
            gc.freeze()  # the parent's objects: never collected here (no finalizer of the parent's runs in the helper)
            _reset_signals()
            parent_conn.close()
            _serve(child_conn, parent)
            code = 0
        finally:
            os._exit(code)  # never the parent's atexit handlers, buffers or finalizers
    child_conn.close()
    return PngProcess(pid, parent_conn)


def _reset_signals() -> None:
    """The parent's Python signal handlers are not the helper's (a SIGTERM to the process group must not run the
    parent's cleanup a second time, in here): the default for each; Ctrl-C ignored (the parent ends the helper)."""
    for sig in signal.valid_signals():
        with contextlib.suppress(OSError, ValueError, TypeError):
            if callable(signal.getsignal(sig)):
                signal.signal(sig, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _close_inherited_files(keep: int) -> None:
    """Close every file the helper inherited but ``keep`` and stdio: the parent's sockets and pipes (a listening
    port, a subprocess's stdin) must not stay open in it for its whole life."""
    try:
        fds = [int(name) for name in os.listdir("/proc/self/fd")]
    except OSError:
        fds = range(3, os.sysconf("SC_OPEN_MAX"))
    for fd in fds:
        if fd > 2 and fd != keep:
            with contextlib.suppress(OSError):
                os.close(fd)


def _encode(mm: mmap.mmap, specs: list[tuple[int, tuple[int, ...]]]) -> list[tuple[list[bytes], dict[str, np.ndarray]]]:
    """Each array's PNGs and image stats (its views of the slot end with this call: a dropped slot can be unmapped)."""
    out = []
    for offset, shape in specs:
        frames = np.ndarray(shape, np.uint8, buffer=mm, offset=offset)
        out.append((encode_png(frames), image_stats(frames)))
    return out


def _serve(conn: Connection, parent: int) -> None:
    """The helper's loop: ``("slot", n)`` + a memory file, ``("encode", n, [(offset, shape), ...])`` (answered
    ``("ok", [(pngs, stats), ...])`` or ``("error", text)``), ``("drop",)``, ``("idle",)`` (released: count down),
    ``("ping",)`` (taken back: answered ``("pong",)``); None, EOF, its parent's death or :data:`IDLE_SECONDS` idle
    end it. A slow env between two episodes is not idleness: only a released helper counts down."""
    _close_inherited_files(conn.fileno())
    maps: dict[int, mmap.mmap] = {}
    idle: float | None = None  # seconds released without a message; None: in use
    while True:
        if not conn.poll(_POLL_S):
            idle = None if idle is None else idle + _POLL_S
            if os.getppid() != parent or (idle is not None and idle >= IDLE_SECONDS):  # orphaned, or not needed
                return
            continue
        idle = None
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        if message[0] == "slot":
            fd = recv_handle(conn)
            try:
                maps[message[1]] = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)  # the old mapping goes with its last view
            finally:
                os.close(fd)
            continue
        if message[0] == "drop":
            maps.clear()
            continue
        if message[0] == "idle":
            idle = 0.0
            continue
        if message[0] == "ping":
            try:
                conn.send(("pong",))
            except OSError:
                return
            continue
        _, slot, specs = message
        try:
            reply: tuple[str, Any] = ("ok", _encode(maps[slot], specs))
        except Exception as exc:  # noqa: BLE001  - reported to the parent, which raises it as a DatasetError
            reply = ("error", f"{type(exc).__name__}: {exc} ({traceback.extract_tb(exc.__traceback__)[-1].name})")
        try:
            conn.send(reply)
        except OSError:  # the parent is gone
            return
