"""A worker process's life: tied to its parent's, its first message, the exit statuses it ends with.

Standard library only (with :mod:`~hub_envs.isolation.doorbell`): a sandboxed worker runs this before its
sandbox is entered, before ``site`` has set up ``site-packages``.
"""

from __future__ import annotations

import os
import pickle
import signal
from multiprocessing.connection import Connection
from typing import Any

from hub_envs.isolation.doorbell import WORKER, Doorbell

#: the worker stopped itself after reporting an error that leaves it unusable (a MemoryError)
FATAL_EXIT = 70
#: the worker could not enter its sandbox (its stderr says why); none of the env's code ran
ENTER_FAILED_EXIT = 71
#: the sandbox's supervisor stopped the worker: its processes together went over the memory limit
MEMORY_EXIT = 72


def set_parent_death_signal(sig: int = signal.SIGKILL) -> bool:
    """Have the kernel send ``sig`` to this process when its parent dies (``prctl(PR_SET_PDEATHSIG)``).

    Args:
        sig: the signal to receive.

    Returns:
        Whether the kernel took it (False where there is no ``prctl``: not Linux).
    """
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(1, int(sig), 0, 0, 0) == 0  # PR_SET_PDEATHSIG = 1
    except Exception:  # pragma: no cover - not Linux
        return False


def leave_realtime() -> None:
    """Run under the normal scheduler, whatever scheduling class the parent had (some libraries make their process
    real-time, and a child inherits it): a busy env must not starve the parent's watchdog."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        pass


def attach_to_parent(argv: list[str]) -> tuple[Connection, Doorbell, dict[str, Any]]:
    """A worker's first steps: die with the parent, leave real-time scheduling, open the channels the parent passed
    and read its init message.

    Args:
        argv: the worker's arguments: its end of the socketpair, then the doorbell's fds
            (:meth:`~hub_envs.isolation.doorbell.Doorbell.fds_for_worker`).

    Returns:
        ``(connection, doorbell, init)``: the init message is plain data (repo@sha, snapshot folder, entry point,
        sandbox settings) from the parent, which the worker trusts.

    Raises:
        EOFError: the parent closed its end before sending the init message. A worker whose parent died before
        the death signal was armed exits at once (status 0).
    """
    set_parent_death_signal()
    leave_realtime()
    conn = Connection(int(argv[0]))
    bell = Doorbell((int(argv[1]), int(argv[2])), sock_fd=conn.fileno(), side=WORKER)
    if os.getppid() == 1:  # the parent died before the death signal was armed
        os._exit(0)
    init = pickle.loads(bell.receive(None, 0.0, lambda _deadline: conn.recv_bytes()))
    return conn, bell, init
