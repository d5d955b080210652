"""Camera episodes PNG-encoded (and their image stats computed) in a forked helper process, in submission order.

Why a process and not a thread: ``zlib.compress`` releases the GIL for each frame and needs it back after; while the
main thread steps a Python env, a thread waits for the GIL at every frame (up to ``sys.getswitchinterval()``, 5 ms),
so an encode thread overlapped nothing (``benchmarks/bench_datagen.py``, image variant: 67 us/frame with one thread,
68 inline). A process has a GIL of its own. Frames go to it through reusable files in ``/dev/shm`` (memory), mapped
by both sides; the PNG bytes and stats come back through a pipe. Where that cannot be had (no ``fork``, no
``/dev/shm``), :func:`acquire` returns None and the writer encodes on a thread as before. A helper that finished its
work stays for the next dataset of this process (:func:`release`): forking it and ending it cost more than encoding a
small dataset's frames; it ends with the process, or on its own if the process dies.

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
import mmap
import multiprocessing
import os
import signal
import sys
import threading
import uuid
from collections import deque
from typing import Any

import numpy as np

from hub_envs.dataset.codec import encode_png
from hub_envs.dataset.stats import image_stats
from hub_envs.errors import DatasetError

__all__ = ["PngProcess", "acquire", "release"]

_SHM = "/dev/shm"
_SLOTS = 2  # episodes in flight: one being encoded, one being written into
_PARENT_POLL_S = 1.0  # how often an idle helper checks that its parent is alive
_KEEP_SLOTS_BYTES = 64 * 2**20  # an idle helper keeps its slots' memory up to this size (a small dataset's frames)
_IDLE: list[PngProcess] = []  # helpers of this process waiting for the next dataset (at most one)
_IDLE_LOCK = threading.Lock()


class PngProcess:
    """The helper process and its frame slots. :meth:`submit` an episode's frame arrays, :meth:`result` takes the
    oldest episode's ``[(pngs, image_stats), ...]`` (one pair per array), :meth:`close` ends it (the files go)."""

    def __init__(self, process: Any, conn: Any, prefix: str):
        self.process, self.conn, self.prefix = process, conn, prefix
        self.owner = os.getpid()  # a process forked from the owner inherits this object, not the helper
        self.maps: list[mmap.mmap | None] = [None] * _SLOTS
        self.paths: list[str | None] = [None] * _SLOTS  # each slot's file: a new name for each new file
        self.files_made = 0
        self.in_flight: deque[int] = deque()  # slots, oldest first
        self.next_slot = 0

    @property
    def full(self) -> bool:
        """Every slot holds an episode not taken back yet: :meth:`result` before the next :meth:`submit`."""
        return len(self.in_flight) == _SLOTS

    def submit(self, arrays: list[np.ndarray]) -> None:
        """Queue one episode: its ``(T, H, W, C)`` uint8 frame arrays (copied into a slot)."""
        if self.full:
            raise DatasetError("PngProcess.submit: every slot is in use; take a result first.")
        slot = self.next_slot
        self.next_slot = (slot + 1) % _SLOTS
        specs, size = [], 0
        for arr in arrays:
            specs.append((size, tuple(arr.shape)))
            size += arr.nbytes
        view = self._slot(slot, size)
        for (offset, shape), arr in zip(specs, arrays):
            np.ndarray(shape, np.uint8, buffer=view, offset=offset)[...] = arr
        self._send((slot, self.paths[slot], specs))
        self.in_flight.append(slot)

    def result(self) -> list[tuple[list[bytes], dict[str, np.ndarray]]]:
        """The oldest submitted episode's ``(pngs, image_stats)`` per array, in the order given."""
        if not self.in_flight:
            raise DatasetError("PngProcess.result: no episode was submitted.")
        try:
            status, payload = self.conn.recv()
        except (EOFError, OSError) as exc:
            self.process.join(timeout=1)
            raise DatasetError(
                f"The PNG encoding process stopped (exit code {self.process.exitcode}) before returning an episode's "
                "frames: it was killed or ran out of memory. Nothing was written; run again, or pass "
                "encode_in_background=False to encode in this process."
            ) from exc
        self.in_flight.popleft()
        if status != "ok":
            raise DatasetError(f"Encoding an episode's frames as PNG failed in the helper process: {payload}")
        return payload

    def close(self, *, wait: bool = True) -> None:
        """End the process (``wait``: let it finish its last message; else kill it) and remove the slot files."""
        with contextlib.suppress(OSError, ValueError):
            if wait and self.process.is_alive():
                self.conn.send(None)
                self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=5)
        with contextlib.suppress(OSError):
            self.conn.close()
        self.drop_slots()

    def drop_slots(self) -> None:
        """Unmap and remove the slot files (the next :meth:`submit` makes them again)."""
        for slot in range(_SLOTS):
            self._drop_slot(slot)

    def _drop_slot(self, slot: int) -> None:
        mm, path = self.maps[slot], self.paths[slot]
        if mm is not None:
            with contextlib.suppress(BufferError, ValueError):  # a view still held: the GC unmaps it
                mm.close()
        if path is not None:
            with contextlib.suppress(OSError):
                os.unlink(path)
        self.maps[slot], self.paths[slot] = None, None

    def _slot(self, slot: int, size: int) -> mmap.mmap:
        """The slot's mapping, grown to hold ``size`` bytes (its pages stay, so a reused slot costs a copy only)."""
        mm = self.maps[slot]
        if mm is not None and len(mm) >= size:
            return mm
        grown = max(size, int(len(mm) * 1.5) if mm is not None else 0, 1)
        self._drop_slot(slot)
        path = f"{self.prefix}{self.files_made}"
        self.files_made += 1
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)  # this user only
        try:
            self.paths[slot] = path
            os.ftruncate(fd, grown)
            self.maps[slot] = mmap.mmap(fd, grown)
        finally:
            os.close(fd)
        return self.maps[slot]

    def _send(self, message: Any) -> None:
        try:
            self.conn.send(message)
        except OSError as exc:
            raise DatasetError(
                f"The PNG encoding process is gone (exit code {self.process.exitcode}). Nothing was written; run "
                "again, or pass encode_in_background=False to encode in this process."
            ) from exc


def acquire() -> PngProcess | None:
    """An idle helper of this process, or a new one; None where none can run (the caller encodes itself).

    Returns:
        A :class:`PngProcess` with no episode in flight; give it back with :func:`release`.
    """
    with _IDLE_LOCK:
        while _IDLE:
            helper = _IDLE.pop()
            if helper.owner == os.getpid() and helper.process.is_alive():
                return helper
            if helper.owner == os.getpid():  # died while idle (killed): its files are ours to remove
                helper.close(wait=False)
    return _start()


def release(helper: PngProcess, *, ok: bool) -> None:
    """Give ``helper`` back: kept for the next dataset when its work ended well (``ok``) and none is kept yet, else
    ended (killed when not ``ok``: an episode may still be in it)."""
    if ok and not helper.in_flight and helper.owner == os.getpid() and helper.process.is_alive():
        if sum(len(mm) for mm in helper.maps if mm is not None) > _KEEP_SLOTS_BYTES:
            helper.drop_slots()  # a big dataset's frames: not held in memory while idle
        with _IDLE_LOCK:
            if not _IDLE:
                _IDLE.append(helper)
                return
    helper.close(wait=ok)


@atexit.register
def _close_idle() -> None:
    """At exit: end this process's idle helpers and remove their files (multiprocessing would only kill them)."""
    with _IDLE_LOCK:
        idle = [h for h in _IDLE if h.owner == os.getpid()]
        _IDLE.clear()
    for helper in idle:
        helper.close()


def _start() -> PngProcess | None:
    """Fork a helper (Linux, with ``/dev/shm`` writable); None where it cannot run."""
    if not sys.platform.startswith("linux") or "fork" not in multiprocessing.get_all_start_methods():
        return None
    if not (os.path.isdir(_SHM) and os.access(_SHM, os.W_OK)):
        return None
    ctx = multiprocessing.get_context("fork")  # the frames' code is already imported: nothing to pickle or import
    parent_conn, child_conn = ctx.Pipe()
    process = ctx.Process(target=_serve, args=(child_conn, os.getpid()), name="hub-envs-png", daemon=True)
    try:
        process.start()
    except OSError:  # no memory or process left to fork: encode in this process
        parent_conn.close()
        child_conn.close()
        return None
    child_conn.close()
    return PngProcess(process, parent_conn, f"{_SHM}/hub-envs-png-{os.getpid()}-{uuid.uuid4().hex[:12]}-")


def _serve(conn: Any, parent: int) -> None:
    """The helper's loop: ``(slot, path, [(offset, shape), ...])`` in, ``("ok", [(pngs, stats), ...])`` out."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it closes this process
    keep = conn.fileno()  # the parent's other files (sockets, pipes to its subprocesses) must not stay open in here
    os.closerange(3, keep)
    os.closerange(keep + 1, os.sysconf("SC_OPEN_MAX"))
    maps: dict[int, tuple[str, mmap.mmap]] = {}  # slot -> its file's name and mapping
    while True:
        while not conn.poll(_PARENT_POLL_S):
            if os.getppid() != parent:  # the parent died without closing: nobody will read
                return
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        slot, path, specs = message
        try:
            if slot not in maps or maps[slot][0] != path:  # a new file for the slot (grown, or made again)
                with open(path, "rb") as f:
                    maps[slot] = (path, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ))
            mm = maps[slot][1]
            out = []
            for offset, shape in specs:
                frames = np.ndarray(shape, np.uint8, buffer=mm, offset=offset)
                out.append((encode_png(frames), image_stats(frames)))
            reply: tuple[str, Any] = ("ok", out)
        except Exception as exc:  # noqa: BLE001  - reported to the parent, which raises it as a DatasetError
            reply = ("error", f"{type(exc).__name__}: {exc}")
        conn.send(reply)
