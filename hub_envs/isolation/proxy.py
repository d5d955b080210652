"""The parent's side of an isolated env: :class:`Worker` (one worker process; every way it can fail is a typed
error) and :class:`IsolatedEnv`, the ``gym.Env`` that ``loaded.make()`` wraps (``docs/isolation.md``).

Example:
    >>> loaded = load_env("user/hover@<sha>", trust_remote_code=True, isolation="process")  # doctest: +SKIP
    >>> env = loaded.make()              # a TimeLimit(OrderEnforcing(IsolatedEnv)), the env in a worker  # doctest: +SKIP
    >>> obs, info = env.reset(seed=0)                                                       # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hub_envs._text import safe_lines, safe_text
from hub_envs.errors import AnswerTooLargeError, EnvCrashedError, EnvTimeoutError, IsolationError
from hub_envs.isolation import affinity
from hub_envs.isolation.affinity import NO_CPU, pin_here, unpin
from hub_envs.isolation.buffers import ObservationBuffers, box_leaves
from hub_envs.isolation.doorbell import (
    MAIL,
    PIN,
    SLEEP,
    SPIN,
    SPINNING,
    Doorbell,
    Oversized,
    PastDeadline,
    SpinBudget,
    WaitChooser,
)
from hub_envs.isolation.lifetime import ENTER_FAILED_EXIT, MEMORY_EXIT
from hub_envs.isolation.options import IsolationOptions
from hub_envs.isolation.protocol import (
    FAST_ANSWER,
    FAST_HEADER,
    MAX_MESSAGE_BYTES,
    InfoDecoder,
    decode_answer,
    dumps,
    read_vector_answer,
    rebuild_error,
)

STDERR_TAIL_LINES = 20
_WORKER_CODE = "from hub_envs.isolation.worker import main; main()"
#: a sandboxed worker: ``-S``, so that nothing of site-packages (a venv's .pth files) runs before the sandbox is entered
_SANDBOX_CODE = "from hub_envs.isolation.sandbox import boot; boot()"


@dataclass(frozen=True)
class EnvTarget:
    """Which code a worker runs: repo@sha, the verified snapshot folder, the env entry point."""

    repo_id: str
    revision: str
    path: Path
    key: str
    entry_point: str
    files: tuple[tuple[str, str], ...] = ()  # manifest sha256 per file (the sandbox verifies its copy)
    requirements: tuple[str, ...] = ()  # the manifest's (a sandbox shows the package folders they need)

    @property
    def where(self) -> str:
        return f"{self.repo_id}@{self.revision}"


def _worker_environ(options: IsolationOptions) -> dict[str, str]:
    paths = [p for p in sys.path if p and os.path.isdir(p)] if options.pythonpath is None else [options.pythonpath]
    if options.sandbox:
        from hub_envs.isolation.sandbox import scrubbed_environ

        env = scrubbed_environ(os.environ)
    else:
        env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.pop("PYTHONSTARTUP", None)
    return env


def _kill_group(proc: subprocess.Popen, owner: int) -> None:
    if os.getpid() != owner:  # a forked copy of the parent does not own this worker
        return
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            try:
                proc.kill()
            except ProcessLookupError:
                pass
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:  # pragma: no cover
        pass
    else:
        try:  # children the env forked are in the same group
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass


def _cleanup(proc: subprocess.Popen, handles: tuple, log_path: str, owner: int, cgroup=None) -> None:
    if os.getpid() != owner:
        return
    for handle in handles:  # the connection, its non-blocking reader, the doorbell
        try:
            handle.close()
        except (OSError, BufferError):
            pass
    _kill_group(proc, owner)
    try:
        os.unlink(log_path)
    except OSError:
        pass
    if cgroup is not None:  # the sandbox's memory cgroup, empty once its processes are gone
        cgroup.remove()


class _Launcher:
    """One long-lived thread per process that starts every worker.

    ``PR_SET_PDEATHSIG`` fires when the *thread* that started the worker ends, not only the process: an env
    made in a short-lived thread (a thread pool, a data loader) would lose its worker with that thread. Workers
    are therefore started from this thread, which lives as long as the process (a forked child gets its own).
    """

    def __init__(self) -> None:
        import queue
        import threading

        self.pid = os.getpid()
        self.requests: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._run, name="hub-envs-worker-launcher", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while True:
            args, kwargs, done = self.requests.get()
            try:
                done.append(("ok", subprocess.Popen(*args, **kwargs)))
            except BaseException as e:  # handed to the caller
                done.append(("err", e))

    def popen(self, *args: Any, **kwargs: Any) -> subprocess.Popen:
        import threading

        event = threading.Event()
        done: list = []

        class _Done(list):
            def append(self, item) -> None:
                done.append(item)
                event.set()

        self.requests.put((args, kwargs, _Done()))
        event.wait()
        status, value = done[0]
        if status == "err":
            raise value
        return value


_LAUNCHER: _Launcher | None = None


def _launch(*args: Any, **kwargs: Any) -> subprocess.Popen:
    global _LAUNCHER
    if _LAUNCHER is None or _LAUNCHER.pid != os.getpid() or not _LAUNCHER.thread.is_alive():
        _LAUNCHER = _Launcher()
    return _LAUNCHER.popen(*args, **kwargs)


def warn_unsent_metadata(desc: dict, where: str) -> None:
    """Warn about the env's metadata entries its worker could not send (they are missing from the proxy's).

    Args:
        desc: the worker's description of the env it made (``metadata_unsent``: the entries' reprs).
        where: repo@sha, to name in the warning.
    """
    if desc.get("metadata_unsent"):
        import warnings

        warnings.warn(
            f"{where}: the env's metadata entries {', '.join(desc['metadata_unsent'])} hold values an isolated env cannot "
            f"send to its parent (hub_envs.isolation.wire); the isolated env's metadata leaves them out.",
            stacklevel=3,
        )


#: the ways a parent may wait for an answer (:class:`~hub_envs.isolation.doorbell.WaitChooser`), in the order they are
#: first used: sleeping never costs much, busy-waiting where it does not pay costs a CPU's time slice a step
WAYS = (SLEEP, SPIN, PIN)
_ALLOWED = {
    (True, True): WAYS,
    (True, False): (SLEEP, SPIN),
    (False, True): (SLEEP, PIN),
    (False, False): (SLEEP,),
}


def begin_wait(chooser: WaitChooser, spins: bool) -> tuple[str, int, set[int] | None]:
    """How to wait for the answer to the step about to be sent (then :func:`~hub_envs.isolation.affinity.unpin`).

    Args:
        chooser: the env's choice of ways so far.
        spins: whether busy-waiting is possible for this step (:attr:`Worker.spins`).

    Returns:
        ``(way, the CPU field of the request, the CPU set to give back to unpin)``: busy-waiting, both sides stay
        awake and nothing is pinned; sleeping on this CPU (:data:`~hub_envs.isolation.doorbell.PIN`), the calling
        thread is pinned where it runs and the worker told to sleep there too; sleeping
        (:data:`~hub_envs.isolation.doorbell.SLEEP`), the scheduler places both.
    """
    way = chooser.next(time.perf_counter(), _ALLOWED[spins, affinity.enabled])
    if way == SPIN:
        return way, SPINNING, None
    if way == PIN:
        return (way, *pin_here())
    return way, NO_CPU, None


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


class Worker:
    """One worker process: start it, ask it things, know how it died (``dead``: the error its next call raises).

    Args:
        target: the env's code the worker imports.
        options: sandbox, interpreter, ``PYTHONPATH``, ``start_timeout``.
        wait: wait until the worker imported the env's code (False: call :meth:`ready` later; the workers of a vector
            env start side by side).
        spin: both sides may busy-wait for each other's answers a short while before sleeping
            (:mod:`~hub_envs.isolation.doorbell`).

    Raises:
        SandboxUnavailableError: a sandboxed worker could not be started or is not in its memory cgroup (nothing
            of the env's code ran).
        EnvCrashedError: the worker died while it imported the env's code.
        EnvTimeoutError: it took longer than ``start_timeout``.
        RemoteEnvError: importing the env's code raised.
    """

    def __init__(self, target: EnvTarget, options: IsolationOptions, *, wait: bool = True, spin: bool = False):
        self.target, self.options = target, options
        self.where = target.where
        self.dead: EnvCrashedError | EnvTimeoutError | None = None
        self._owner = os.getpid()
        log = tempfile.NamedTemporaryFile(prefix="hub-envs-worker-", suffix=".log", delete=False)
        self.log_path = log.name
        parent_sock, child_sock = socket.socketpair()
        try:
            self.bell = Doorbell(sock_fd=parent_sock.fileno())
        except BaseException:
            parent_sock.close()
            child_sock.close()
            raise
        self.bell.mail = spin and MAIL  # a single env's short messages travel in the shared page
        self._spin = SpinBudget(spin)
        self._infos = InfoDecoder()
        self._sent_at = 0.0
        self._poller: select.poll | None = None
        preexec = None
        init: dict[str, Any] = {
            "where": target.where,
            "path": str(target.path),
            "key": target.key,
            "entry_point": target.entry_point,
        }
        t0 = time.perf_counter()
        self.cgroup = None
        try:
            if options.sandbox:
                from hub_envs.isolation.sandbox import memory_cgroup_for, sandbox_init, sandbox_preexec

                self.cgroup = memory_cgroup_for(options)  # one memory limit for every process of the sandbox
                init["sandbox"] = sandbox_init(target, options, self.cgroup)
                preexec = sandbox_preexec(self.cgroup)
            self.proc = _launch(
                [options.python or sys.executable]
                + (["-S", "-P", "-c", _SANDBOX_CODE] if options.sandbox else ["-P", "-c", _WORKER_CODE])
                + [str(child_sock.fileno())]
                + [str(fd) for fd in self.bell.fds_for_worker()],
                pass_fds=(child_sock.fileno(), *self.bell.fds_for_worker()),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                env=_worker_environ(options),
                # its own process group (killed whole, never sent the terminal's Ctrl-C); a new session only when
                # sandboxed (no controlling terminal to write to or push input into, TIOCSTI): a session is also an
                # autogroup of the scheduler, and a worker in an autogroup of its own waits far longer for a CPU
                # on a busy machine than one in its parent's
                start_new_session=options.sandbox,
                process_group=None if options.sandbox else 0,
                preexec_fn=preexec,
                cwd="/" if options.sandbox else None,
            )
        except BaseException as e:  # nothing started: nothing left open
            self.bell.close()
            parent_sock.close()
            os.unlink(self.log_path)
            if self.cgroup is not None:
                self.cgroup.remove()
            if isinstance(e, subprocess.SubprocessError) and options.sandbox:  # the preexec_fn failed: say so, typed
                from hub_envs.errors import SandboxUnavailableError

                raise SandboxUnavailableError(
                    f"{target.where}: the sandboxed worker could not be started ({e}): joining its memory cgroup or "
                    f"making its namespaces failed. Nothing was started."
                ) from None
            raise
        finally:
            child_sock.close()
            log.close()
        from multiprocessing.connection import Connection

        self.conn = Connection(parent_sock.detach())
        self._rsock = socket.socket(fileno=os.dup(self.conn.fileno()))  # reads without waiting (MSG_DONTWAIT)
        self.pid = self.proc.pid
        self._finalizer = weakref.finalize(
            self,
            _cleanup,
            self.proc,
            (self.conn, self._rsock, self.bell),
            self.log_path,
            self._owner,
            self.cgroup,
        )
        if self.cgroup is not None and not self.cgroup.holds(self.pid):  # fail closed: a worker outside its limit
            self._kill()
            self._finalizer()
            from hub_envs.errors import SandboxUnavailableError

            raise SandboxUnavailableError(
                f"{target.where}: the sandboxed worker (pid {self.pid}) is not in its memory cgroup {self.cgroup.path}; "
                f"it was stopped before it ran anything."
            )
        self._t0 = t0
        self.start_seconds: float | None = None
        self.send("init", init, raw=True)
        if wait:
            self.ready()

    def ready(self) -> None:
        """Wait until the worker imported the env's code (workers of a vector env start side by side)."""
        if self.start_seconds is None:
            self.receive("init", timeout=self.options.start_timeout)
            self.start_seconds = time.perf_counter() - self._t0

    def send_fds(self, fds: list[int]) -> None:
        """Hand file descriptors to the worker (``SCM_RIGHTS``), right after a message that tells it to expect them.

        Args:
            fds: the descriptors (the worker gets its own copies).
        """
        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        try:
            socket.send_fds(sock, [b"F"], fds)
        finally:
            sock.close()

    # -- requests --
    def request(self, op: str, *args: Any, timeout: float | None = None, raw: bool = False) -> Any:
        """Send a request and wait for its answer.

        Args:
            op: the request's name (the worker's ``Server.op_<op>`` answers it).
            *args: its arguments (pickled).
            timeout: seconds from the send to the answer (None: no watchdog).
            raw: send ``args[0]`` itself (the init message).

        Returns:
            The answer's value.

        Raises:
            RemoteEnvError: the env raised (the worker lives on).
            EnvCrashedError: the worker died, or sent what is not an answer (it is stopped).
            EnvTimeoutError: no answer within ``timeout`` (the worker is killed).
            AnswerTooLargeError: the answer would build far more than it weighs (the worker lives on).
        """
        self.send(op, *args, raw=raw)
        return self.receive(op, timeout=timeout)

    def send(self, op: str, *args: Any, raw: bool = False) -> None:
        """The first half of :meth:`request` (send to several workers, then :meth:`receive` from each).

        Args:
            op: the request's name.
            *args: its arguments.
            raw: send ``args[0]`` itself.

        Raises:
            EnvCrashedError: the worker is dead (or died now).
        """
        if self.dead is not None:
            raise self.dead
        try:
            self.bell.send(dumps(args[0] if raw else (op, *args)), self.conn.send_bytes)
        except KeyboardInterrupt:  # maybe half sent: the worker's stream would be out of step
            self.interrupted(op)
            raise
        except (OSError, EOFError):
            raise self._died(op) from None
        self._sent_at = time.perf_counter()

    def send_raw(self, data: bytes) -> None:
        """Send bytes as they are (the fast step path).

        Args:
            data: :data:`~hub_envs.isolation.protocol.FAST_HEADER` and the action bytes.

        Raises:
            EnvCrashedError: the worker is dead (or died now).
        """
        if self.dead is not None:
            raise self.dead
        try:
            self.bell.send(data, self.conn.send_bytes)
        except KeyboardInterrupt:
            self.interrupted("step")
            raise
        except (OSError, EOFError):
            raise self._died("step") from None
        self._sent_at = time.perf_counter()

    def interrupted(self, op: str) -> None:
        """The caller stopped waiting for an answer (Ctrl-C): stop the worker, since that answer would come back as
        the answer to the next call.

        Args:
            op: the call that was interrupted (named in the error the next call raises).
        """
        if self.dead is not None:
            return
        self._kill()
        self.dead = EnvCrashedError(
            f"{self.where}: interrupted (Ctrl-C) while the env's worker process (pid {self.pid}) ran {op}; it was "
            f"stopped, since its answer would have come back as the answer to the next call. With restart=True, "
            f"reset() starts a fresh worker; otherwise make a new env."
        )

    @property
    def spins(self) -> bool:
        """Whether busy-waiting is possible for the next step: the answers' usual wait is short, this process may use
        more than one CPU, busy-waiting is on (``doorbell.enabled``) and the worker was made to (``spin``)."""
        return self._spin.seconds() > 0

    def receive(self, op: str, timeout: float | None = None, *, spin: bool = True) -> Any:
        """The second half of :meth:`request`.

        Args:
            op: the request's name (in errors).
            timeout: seconds from the send to the answer (None: no watchdog).
            spin: busy-wait a while first if :attr:`spins` (False: sleep at once).

        Returns:
            The answer's value.

        Raises:
            as :meth:`request`.
        """
        return self._decode(op, self._wait(op, timeout, spin))

    def receive_step(self, timeout: float | None = None, *, spin: bool = True) -> tuple:
        """The answer to a single env's fast step (a :data:`~hub_envs.isolation.protocol.FAST_ANSWER` or an encoded
        answer).

        Args:
            timeout: seconds from the send to the answer (None: no watchdog).
            spin: busy-wait a while first if :attr:`spins` (False: sleep at once).

        Returns:
            ``(reward, terminated, truncated, info, obs, shared)``; ``shared``: the observation is in shared memory
            and ``obs`` is None.

        Raises:
            as :meth:`request`.
        """
        data = self._wait("step", timeout, spin)
        if data[:1] != b"F":
            answer = self._decode("step", data)
            if type(answer) is not tuple or len(answer) != 6 or type(answer[5]) is not bool:
                raise self.garbled("step", ValueError(f"a step answer of type {type(answer).__name__}"))
            return answer
        try:
            _, reward, terminated, truncated = FAST_ANSWER.unpack_from(data)
            info = self._infos(data[FAST_ANSWER.size :])
            if type(info) is not dict:
                raise ValueError(f"a fast step answer whose info is a {type(info).__name__}")
        except AnswerTooLargeError as e:
            raise AnswerTooLargeError(f"{self.where}: {e} (in step)") from None
        except Exception as e:
            raise self.garbled("step", e) from None
        return reward, terminated, truncated, info, None, True

    def _wait(self, op: str, timeout: float | None, spin: bool = True) -> bytes:
        """The bytes of the next answer, within ``timeout`` of the last send (the watchdog)."""
        if self.dead is not None:
            raise self.dead
        try:
            budget = self._spin.seconds() if spin else 0.0
            spin_until = self._sent_at + (min(budget, timeout) if timeout is not None else budget) if budget else 0.0
            # the watchdog holds whatever the worker writes into the shared page (see doorbell)
            data = self.bell.receive(None if timeout is None else self._sent_at + timeout, spin_until, self._recv_by)
        except KeyboardInterrupt:
            self.interrupted(op)
            raise
        except Oversized as e:
            self._kill()
            self.dead = EnvCrashedError(
                f"{self.where}: the env's worker process (pid {self.pid}) announced an answer of {e.args[0]} bytes to {op}, "
                f"more than the {e.args[1]} it may send that way; it was stopped. Return smaller observations "
                f"or infos from the env."
            )
            raise self.dead from None
        except PastDeadline:
            self._kill()
            self.dead = EnvTimeoutError(
                f"{self.where}: {op} took longer than step_timeout={timeout:g} s; the env's worker process (pid {self.pid}) "
                f"was killed. Raise step_timeout if the env is just slow; reset() starts a fresh worker with restart=True."
            )
            raise self.dead from None
        except (OSError, EOFError):
            raise self._died(op) from None
        if self._spin.active and op in ("step", "vstep"):  # how long a step takes (a make or reset says nothing of it)
            self._spin.observe(time.perf_counter() - self._sent_at)
        return data

    def garbled(self, op: str, e: Exception) -> EnvCrashedError:
        """Stop the worker for an answer that is not one (or carries a forbidden type).

        Args:
            op: the call it answered.
            e: what was wrong with it.

        Returns:
            The :class:`~hub_envs.errors.EnvCrashedError` to raise (also the worker's ``dead``).
        """
        self._kill()
        if isinstance(e, IsolationError):
            self.dead = EnvCrashedError(f"{self.where}: {safe_text(e)} (in {op}; the worker was stopped)")
        else:  # not a message a worker sends: something else wrote it (the env's code)
            self.dead = EnvCrashedError(
                f"{self.where}: the env's worker process (pid {self.pid}) sent an answer to {op} that is not one "
                f"({type(e).__name__}: {safe_text(e)}); it was stopped. The env's code wrote to its worker's socket or shared page."
            )
        return self.dead

    def _decode(self, op: str, data: bytes) -> Any:
        try:
            if data[:1] == b"V" and op == "vstep":  # a vector slice's step (observations in shared memory)
                return read_vector_answer(data, self._infos)
            status, value = decode_answer(data)
        except AnswerTooLargeError as e:  # refused before it was built; the worker's stream is in step: it goes on
            raise AnswerTooLargeError(f"{self.where}: {e} (in {op})") from None
        except Exception as e:
            raise self.garbled(op, e) from None
        if status == "ok":
            return value
        if status == "fatal":
            raise self._died(op, reason=f"{value.get('qualname')}: {value.get('message')}", remote=value)
        raise rebuild_error(value, self.where, op)

    def _recv_by(self, deadline: float | None) -> bytes:
        """One message (``Connection``'s framing) read whole before ``deadline`` (a ``perf_counter`` value; None:
        no watchdog): a worker that sends part of a message and stops (env code can write to its socket) meets
        the watchdog like one that sends nothing (``PastDeadline``); one that announces more than
        :data:`~hub_envs.isolation.protocol.MAX_MESSAGE_BYTES` is stopped before anything is read (``Oversized``)."""
        (size,) = struct.unpack("!i", self._read_by(4, deadline))
        if size == -1:
            (size,) = struct.unpack("!Q", self._read_by(8, deadline))
        if size < 0 or size > MAX_MESSAGE_BYTES:
            raise Oversized(size, MAX_MESSAGE_BYTES)
        return self._read_by(size, deadline)

    def _read_by(self, n: int, deadline: float | None) -> bytes:
        if self._poller is None:
            self._poller = select.poll()
            self._poller.register(self.conn.fileno(), select.POLLIN)
        chunks = []
        while n:
            try:  # what is there already (the usual case after a busy-wait) costs no poll
                chunk = self._rsock.recv(min(n, 1 << 20), socket.MSG_DONTWAIT)
            except BlockingIOError:
                # an answer already there is taken even at (or past) the deadline: a vector env reads its workers in turn
                wait = None if deadline is None else max(0, math.ceil((deadline - time.perf_counter()) * 1000))
                if not self._poller.poll(wait):
                    raise PastDeadline from None
                continue
            if not chunk:
                raise EOFError
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

    def _died(self, op: str, reason: str | None = None, remote: dict | None = None) -> EnvCrashedError:
        try:
            code = self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            code = None
        self._kill()
        over = self.cgroup is not None and (code == MEMORY_EXIT or self.cgroup.breached())
        if over:  # the kernel's count, not a guess from the exit status
            how = (
                f"went over the sandbox's memory limit of {self.cgroup.limit_mb} MB (all its processes together: the "
                f"kernel's memory cgroup counted an out-of-memory kill) and was stopped with everything it started"
            )
        elif reason is not None:
            how = f"stopped after {safe_text(reason)}" + (
                f" (the sandbox's memory limit is {self.options.memory_mb} MB per process)"
                if self.options.sandbox and "MemoryError" in reason
                else ""
            )
        elif self.options.sandbox and code == ENTER_FAILED_EXIT:
            how = "could not enter its sandbox (its stderr says why) and was stopped before any of the env's code ran"
        elif code is None:
            how = "stopped answering"
        elif code < 0:
            how = f"was killed by {_signal_name(code)}" + (" (out of memory?)" if code == -signal.SIGKILL else "")
        else:
            how = f"exited with code {code}"
        tail = self.stderr_tail()
        self.dead = EnvCrashedError(
            f"{self.where}: the env's worker process (pid {self.pid}) {how} during {op}.\n"
            + (f"Last lines of its stderr:\n{tail}\n" if tail else "It wrote nothing to stderr.\n")
            + ("Remote traceback:\n" + safe_lines(remote.get("traceback", "")) if remote else "")
            + "The env is gone: with restart=True, reset() starts a fresh worker; otherwise make a new env."
        )
        return self.dead

    def stderr_tail(self, lines: int = STDERR_TAIL_LINES) -> str:
        """The last lines the worker wrote to its stderr and stdout (escaped: the env's text).

        Args:
            lines: how many.

        Returns:
            The lines, indented, joined ("" when there are none).
        """
        try:
            with open(self.log_path, "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - 16384))
                text = f.read().decode("utf-8", "replace")
        except OSError:
            return ""
        return "\n".join("  " + safe_text(line) for line in text.splitlines()[-lines:])  # env output: escaped

    def _kill(self) -> None:
        _kill_group(self.proc, self._owner)

    @property
    def alive(self) -> bool:
        return self.dead is None and self.proc.poll() is None

    def close(self) -> None:
        """Ask the worker to exit, then make sure it did (and everything it started)."""
        if os.getpid() != self._owner:
            return
        if self.dead is None and self.proc.poll() is None:
            try:
                self.bell.send(dumps(("exit",)), self.conn.send_bytes)
                self.proc.wait(timeout=2)
            except (OSError, EOFError, subprocess.TimeoutExpired):
                pass
        self._finalizer()


class IsolatedEnv(gym.Env):
    """A ``gym.Env`` whose env runs in a worker process: spaces, ``reset``/``step``/``render``/``close``, and
    ``get_state``/``reset_to`` when the env has them (else they are missing, as on the env).

    Args:
        target: the env's code (repo@sha, verified folder, entry point).
        options: how it runs (``sandbox``, ``step_timeout``, ``restart``, ...).
        kwargs: the env's constructor arguments.

    Raises:
        EnvCrashedError: the worker died while it started or built the env.
        EnvTimeoutError: building the env took longer than ``start_timeout``.
        RemoteEnvError: the env's code raised while it was imported or built.
    """

    def __init__(self, target: EnvTarget, options: IsolationOptions, kwargs: dict[str, Any]):
        self._target, self._options, self._kwargs = target, options, dict(kwargs)
        self._worker: Worker | None = None
        self._fast = None
        self._fast_buffers = None
        self._closed = False
        self._state_methods: tuple[str, ...] = ()
        self._waits = WaitChooser(WAYS)
        self._start()

    def _start(self) -> None:
        self._worker = Worker(self._target, self._options, spin=True)
        desc = self._worker.request("make", 0, self._kwargs, timeout=self._options.start_timeout)
        self.observation_space = desc["observation_space"]
        self.action_space = desc["action_space"]
        self.metadata = desc["metadata"]
        warn_unsent_metadata(desc, self._target.where)
        self.render_mode = desc["render_mode"]
        self._state_methods = tuple(desc["state_methods"])
        self._arm_fast_step()

    def _has(self, name: str) -> None:
        if name not in self._state_methods:  # hasattr(env, name) is False, as on the env itself
            raise AttributeError(f"{self._target.where}: the env has no {name}")

    @property
    def get_state(self) -> Callable[[], Any]:
        """The env's ``get_state()``, run in its worker (an AttributeError when the env has none)."""
        self._has("get_state")
        return lambda: self._call("call", "get_state", ())

    @property
    def reset_to(self) -> Callable[[Any], Any]:
        """The env's ``reset_to(state)``, run in its worker (an AttributeError when the env has none)."""
        self._has("reset_to")
        return lambda state: self._call("call", "reset_to", (state,))

    @property
    def worker(self) -> Worker | None:
        """The current worker (its ``pid``, ``start_seconds``, ``stderr_tail()``)."""
        return self._worker

    def _call(self, op: str, *args: Any) -> Any:
        if self._closed:
            raise IsolationError(f"{self._target.where}: {op} on a closed isolated env. Make a new one.")
        return self._worker.request(op, 0, *args, timeout=self._options.call_timeout)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """The env's ``reset`` in its worker (with ``restart=True``, after a crash or a timeout, in a fresh worker).

        Args:
            seed: as gymnasium's.
            options: as gymnasium's.

        Returns:
            ``(observation, info)``.

        Raises:
            RemoteEnvError: the env raised (the worker lives on).
            EnvCrashedError: the worker died, or sent what is not an answer (it is stopped).
            EnvTimeoutError: no answer within the step timeout (the worker is killed).
            AnswerTooLargeError: the answer would build far more than it weighs (the worker lives on).
        """
        if self._worker is not None and self._worker.dead is not None and self._options.restart and not self._closed:
            self._worker.close()
            self._start()
        self._waits.forget_last()  # the time from the last step to the next one holds this reset
        return self._call("reset", seed, options)

    def _arm_fast_step(self) -> None:
        """With a Box action space and an observation space of Boxes, ``step`` sends the action as raw bytes
        and the worker writes the observation into shared memory (nothing encoded but the small rest)."""
        self._fast = None
        if self._fast_buffers is not None:
            self._fast_buffers.close()
            self._fast_buffers = None
        leaves = box_leaves(self.observation_space)
        act = self.action_space
        if leaves is None or not isinstance(act, gym.spaces.Box):
            return
        buffers = ObservationBuffers(leaves, 1)
        try:
            self._worker.send("fast", leaves, np.dtype(act.dtype).str, tuple(act.shape), len(buffers.fds))
            self._worker.send_fds(buffers.fds)
            self._worker.receive("fast", timeout=self._options.start_timeout)
        except BaseException:
            buffers.close()
            raise
        self._fast_buffers = buffers
        self._fast = (np.dtype(act.dtype), tuple(act.shape))

    def step(self, action: Any) -> tuple:
        """The env's ``step`` in its worker (a Box action as raw bytes, the observation through shared memory).

        Args:
            action: as gymnasium's.

        Returns:
            ``(observation, reward, terminated, truncated, info)``, exactly as the env returned them.

        Raises:
            RemoteEnvError: the env raised (the worker lives on).
            EnvCrashedError: the worker died, or sent what is not an answer (it is stopped).
            EnvTimeoutError: no answer within the step timeout (the worker is killed).
            AnswerTooLargeError: the answer would build far more than it weighs (the worker lives on).
        """
        fast = self._fast
        if fast is not None and type(action) is np.ndarray and action.dtype == fast[0] and action.shape == fast[1]:
            if self._closed:
                raise IsolationError(f"{self._target.where}: step on a closed isolated env. Make a new one.")
            worker = self._worker
            way, cpu, saved = begin_wait(self._waits, worker.spins)
            try:
                worker.send_raw(FAST_HEADER.pack(b"s", cpu) + action.tobytes())
                reward, terminated, truncated, info, obs, shared = worker.receive_step(
                    self._options.call_timeout, spin=way == SPIN
                )
            finally:
                unpin(saved)
            return (self._fast_buffers.read_one() if shared else obs), reward, terminated, truncated, info
        return self._call("step", action)

    def render(self) -> Any:
        """The env's ``render()``, in its worker."""
        return self._call("render")

    def close(self) -> None:
        """Close the env, then its worker (again: nothing)."""
        if self._closed:
            return
        self._closed = True
        worker = self._worker
        if worker is not None:
            if worker.alive:
                try:
                    worker.request("close", 0, timeout=self._options.call_timeout or 30.0)
                except Exception:
                    pass
            worker.close()
        if self._fast_buffers is not None:
            self._fast_buffers.close()
            self._fast_buffers = None

    def __repr__(self) -> str:
        pid = self._worker.pid if self._worker is not None else None
        return f"<IsolatedEnv {self._target.where} pid={pid}{' sandboxed' if self._options.sandbox else ''}>"


class IsolatedEnvFactory:
    """The entry point load_env registers with gymnasium for an isolated env: ``factory(**gym_kwargs)`` is an
    :class:`IsolatedEnv`.

    Args:
        target: the env's code.
        options: how it runs.
    """

    def __init__(self, target: EnvTarget, options: IsolationOptions):
        self.target, self.options = target, options

    def __call__(self, **kwargs: Any) -> IsolatedEnv:
        return IsolatedEnv(self.target, self.options, kwargs)

    def __repr__(self) -> str:
        return f"IsolatedEnvFactory({self.target.where}, isolation={self.options.isolation!r}, sandbox={self.options.sandbox})"
