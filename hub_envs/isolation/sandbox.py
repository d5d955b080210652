"""``sandbox=True``: an isolated env's worker confined with the kernel's own mechanisms (namespaces, a fresh
read-only root, one memory cgroup, no privileges, an allow-listed environment), each part checked, none silently
missing. What it shows and hides: ``docs/security.md``; how it is built: ``docs/isolation.md``.

Example:
    >>> from hub_envs.isolation.sandbox import scrubbed_environ
    >>> sorted(scrubbed_environ({"HF_TOKEN": "hf_x", "AWS_SECRET_ACCESS_KEY": "k", "PATH": "/usr/bin"}))
    ['HOME', 'PATH', 'TMPDIR']
"""

from __future__ import annotations

import ctypes
import hashlib
import itertools
import json
import os
import platform
import re
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hub_envs.errors import HubEnvsWarning, IntegrityError, SandboxUnavailableError
from hub_envs.isolation.lifetime import ENTER_FAILED_EXIT, MEMORY_EXIT, attach_to_parent, set_parent_death_signal
from hub_envs.paths import PACKAGE_DIR

CLONE_NEWNS = 0x00020000
CLONE_NEWPID = 0x20000000
CLONE_NEWNET = 0x40000000
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC = 1, 2, 4, 8
MS_REMOUNT, MS_BIND, MS_REC, MS_PRIVATE = 32, 4096, 16384, 1 << 18
PR_SET_NO_NEW_PRIVS = 38
NOBODY = 65534
SANDBOX_TMP = "/tmp"
ENV_DIR = "/tmp/env"  # the private, verified, read-only copy of the env's code
HOME_DIR = "/tmp/home"
WORK_DIR = "/tmp/work"
#: the system folders a sandbox shows (read-only), those of them this machine has; nothing else of the host's
#: file system is there but the Python folders the env needs (``sandbox_init``)
SYSTEM_DIRS = ("/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32", "/etc", "/dev", "/sys")
_PIVOT_ROOT = {"x86_64": 155, "aarch64": 41, "riscv64": 41}  # syscall numbers: glibc has no pivot_root()

#: environment variables a sandboxed worker keeps (everything else, every token and key, is dropped)
ALLOWED_ENV = (
    "PATH",
    "LANG",
    "LANGUAGE",
    "TZ",
    "TERM",
    "PYTHONHASHSEED",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
)
_SKIP_PREFIXES = ("dataset/", "media/")  # what a sandbox does not copy: the env never needs the published data


def _libc():
    return ctypes.CDLL(None, use_errno=True)


def _check(ret: int, what: str) -> None:
    if ret != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def _unshare(flags: int) -> None:
    _check(_libc().unshare(flags), f"unshare({flags:#x})")


def _mount(source: str | None, target: str, fstype: str | None, flags: int, data: str | None = None) -> None:
    enc = lambda s: s.encode() if s is not None else None  # noqa: E731
    _check(_libc().mount(enc(source), enc(target), enc(fstype), ctypes.c_ulong(flags), enc(data)), f"mount {target}")


def _pivot_root(new_root: str, put_old: str) -> None:
    number = _PIVOT_ROOT.get(platform.machine())
    if number is None:
        raise OSError(38, f"pivot_root: no syscall number known for {platform.machine()}")
    _check(_libc().syscall(ctypes.c_long(number), new_root.encode(), put_old.encode()), f"pivot_root {new_root}")


def scrubbed_environ(environ: dict[str, str]) -> dict[str, str]:
    """The environment of a sandboxed worker.

    Args:
        environ: the parent's environment.

    Returns:
        Its :data:`ALLOWED_ENV` and ``LC_*`` variables only, with ``HOME`` and ``TMPDIR`` in the private /tmp.
    """
    env = {k: v for k, v in environ.items() if k in ALLOWED_ENV or k.startswith("LC_")}
    env["HOME"] = HOME_DIR
    env["TMPDIR"] = SANDBOX_TMP
    return env


def unshare_namespaces() -> None:
    """``preexec_fn`` of a sandboxed worker: new mount, network and pid namespaces (the child, before exec)."""
    _unshare(CLONE_NEWNS | CLONE_NEWNET | CLONE_NEWPID)


def sandbox_preexec(cgroup: MemoryCgroup | None) -> Callable[[], None]:
    """The ``preexec_fn`` of a sandboxed worker: join its memory cgroup (so every process it starts is counted
    there), then :func:`unshare_namespaces`.

    Args:
        cgroup: the sandbox's memory cgroup, or None (nothing to join).
    """
    if cgroup is None:
        return unshare_namespaces

    def preexec() -> None:
        cgroup.join()
        unshare_namespaces()

    return preexec


# --- one memory limit for the whole sandbox ----------------------------------------------------------


def _mounts() -> list[tuple[str, str, str]]:
    """``(mount point, fs type, super options)`` of every mount this process sees."""
    out = []
    with open("/proc/self/mountinfo") as f:
        for line in f:
            left, _, right = line.partition(" - ")
            fields, rest = left.split(), right.split()
            if len(fields) > 4 and len(rest) >= 3:
                out.append((fields[4].replace("\\040", " "), rest[0], rest[2]))
    return out


def _read(path: str) -> str:
    with open(path) as f:
        return f.read()


def _write(path: str, value: str) -> None:
    with open(path, "w") as f:
        f.write(value)


def _try_cgroup(parent: str, version: int) -> str | None:
    """None if a memory-limited cgroup can be made under ``parent`` (made and removed again), else why not."""
    test = os.path.join(parent, f"hub-envs-probe-{os.getpid()}")
    try:
        os.mkdir(test)
    except FileExistsError:
        pass
    except OSError as e:
        return f"cannot create a cgroup in {parent} ({e.strerror})"
    try:
        _write(os.path.join(test, "memory.max" if version == 2 else "memory.limit_in_bytes"), str(64 * 2**20))
        return None
    except OSError as e:
        return f"cannot set a memory limit in {parent} ({e.strerror})"
    finally:
        try:
            os.rmdir(test)
        except OSError:
            pass


_HOME: tuple[str, int] | str | None = None


def cgroup_home(refresh: bool = False) -> tuple[str, int] | str:
    """Where this process can make a sandbox's memory cgroup.

    cgroup v2: the folder of this process's own cgroup when the memory controller is enabled for its children
    (the root cgroup), else its parent's (a sibling of this process's cgroup) when it is enabled there; this
    never enables a controller itself. cgroup v1: a child of this process's cgroup of the memory hierarchy.

    Args:
        refresh: look again (the answer is kept for the process otherwise).

    Returns:
        ``(folder, cgroup version)``, else why not (text).
    """
    global _HOME
    if _HOME is not None and not refresh:
        return _HOME
    why = []
    try:
        mounts = _mounts()
        own: dict[str, str] = {}
        for line in _read("/proc/self/cgroup").splitlines():
            _, controllers, path = line.split(":", 2)
            own[controllers] = path
    except (OSError, ValueError) as e:
        _HOME = f"cannot read this process's cgroups ({e})"
        return _HOME
    v2 = [mp for mp, fstype, _ in mounts if fstype == "cgroup2"]
    if v2 and "" in own:
        here = os.path.normpath(v2[0] + own[""])
        for parent in dict.fromkeys((here, os.path.dirname(here))):
            if not (parent == v2[0] or parent.startswith(v2[0].rstrip("/") + "/")):
                continue
            try:
                enabled = _read(os.path.join(parent, "cgroup.subtree_control")).split()
            except OSError as e:
                why.append(f"{parent}: {e.strerror}")
                continue
            if "memory" not in enabled:
                why.append(f"cgroup v2 {parent}: the memory controller is not enabled for its children")
                continue
            problem = _try_cgroup(parent, 2)
            if problem is None:
                _HOME = (parent, 2)
                return _HOME
            why.append(f"cgroup v2: {problem}")
    v1 = [mp for mp, fstype, opts in mounts if fstype == "cgroup" and "memory" in opts.split(",")]
    key = next((k for k in own if "memory" in k.split(",")), None)
    if v1 and key is not None:
        parent = os.path.normpath(v1[0] + own[key])
        problem = _try_cgroup(parent, 1)
        if problem is None:
            _HOME = (parent, 1)
            return _HOME
        why.append(f"cgroup v1: {problem}")
    _HOME = "; ".join(why) or "no cgroup file system with the memory controller is mounted"
    return _HOME


def breached(counters: str) -> bool:
    """Whether a memory cgroup's OOM counters say it ran out of memory.

    Args:
        counters: the text of v2's ``memory.events`` or v1's ``memory.oom_control``.

    >>> breached("low 0\\nhigh 0\\nmax 3\\noom 0\\noom_kill 0"), breached("oom_kill_disable 0\\nunder_oom 0\\noom_kill 1")
    (False, True)
    """
    values = dict(line.split(" ", 1) for line in counters.splitlines() if line.count(" ") == 1)
    return any(values.get(key, "0").strip() not in ("0", "") for key in ("oom", "oom_kill", "under_oom"))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


class MemoryCgroup:
    """The memory cgroup of one sandboxed worker: the worker and every process the env starts count against one
    limit (``memory.max`` with no swap and ``memory.oom.group`` on cgroup v2; ``memory.limit_in_bytes`` and
    ``memory.memsw.limit_in_bytes`` on v1). Made by the parent before the worker starts, joined by the worker
    before it executes (:func:`sandbox_preexec`), removed when it ends.

    Args:
        limit_mb: the limit, in MB, for all the sandbox's processes together.

    Raises:
        SandboxUnavailableError: the cgroup could not be made or its limit not set (nothing was started).
    """

    _count = itertools.count()
    _NAME = re.compile(r"^hub-envs-sandbox-(\d+)-\d+$")

    def __init__(self, limit_mb: int):
        home = cgroup_home()
        if isinstance(home, str):
            raise SandboxUnavailableError(f"sandbox=True: no memory cgroup can be made here ({home}); the env was not started.")
        parent, self.version = home
        self.limit_mb = int(limit_mb)
        self._remove_stale(parent)
        self.path = os.path.join(parent, f"hub-envs-sandbox-{os.getpid()}-{next(self._count)}")
        limit = str(self.limit_mb * 2**20)
        try:
            os.mkdir(self.path)
            if self.version == 2:
                _write(self._file("memory.max"), limit)
                for name, value in (("memory.swap.max", "0"), ("memory.oom.group", "1")):
                    if os.path.exists(self._file(name)):
                        _write(self._file(name), value)
                applied = _read(self._file("memory.max")).strip()
            else:
                _write(self._file("memory.limit_in_bytes"), limit)
                if os.path.exists(self._file("memory.memsw.limit_in_bytes")):  # memory and swap together
                    _write(self._file("memory.memsw.limit_in_bytes"), limit)
                applied = _read(self._file("memory.limit_in_bytes")).strip()
            if applied != limit:  # fail closed: a limit the kernel did not take is no limit
                raise OSError(0, f"the kernel kept {applied} for a limit of {limit} bytes")
        except OSError as e:
            self.remove()
            raise SandboxUnavailableError(
                f"sandbox=True: the sandbox's memory cgroup ({self.path}) could not be set up ({e.strerror or e}); "
                f"the env was not started."
            ) from None

    def _file(self, name: str) -> str:
        return os.path.join(self.path, name)

    @classmethod
    def _remove_stale(cls, parent: str) -> None:
        """Remove the empty cgroups of sandboxes whose parent process is gone (it was killed before it could)."""
        try:
            names = os.listdir(parent)
        except OSError:
            return
        for name in names:
            found = cls._NAME.match(name)
            if found and not _alive(int(found.group(1))):
                try:
                    os.rmdir(os.path.join(parent, name))
                except OSError:
                    pass

    def join(self) -> None:
        """Move this process into the cgroup (a worker's ``preexec_fn``: everything it starts is counted here)."""
        _write(self._file("cgroup.procs"), str(os.getpid()))

    def holds(self, pid: int) -> bool:
        """Whether a process is in the cgroup (a worker outside it is stopped before it runs anything).

        Args:
            pid: the process.
        """
        try:
            return str(pid) in _read(self._file("cgroup.procs")).split()
        except OSError:
            return False

    def breached(self) -> bool:
        """Whether the sandbox went over its limit (the kernel found nothing to reclaim, and killed or stalled)."""
        try:
            return breached(_read(self._file("memory.events" if self.version == 2 else "memory.oom_control")))
        except OSError:
            return False

    def watch(self) -> dict[str, Any]:
        """What the worker's supervisor watches (:func:`_supervise`), as the init message carries it."""
        return {"path": self.path, "version": self.version, "limit_mb": self.limit_mb}

    def remove(self) -> None:
        """Remove the cgroup once its processes are gone (they are being reaped: a few tries)."""
        import time

        for _ in range(50):
            try:
                os.rmdir(self.path)
                return
            except FileNotFoundError:
                return
            except OSError:
                time.sleep(0.02)


def memory_cgroup_for(options: Any) -> MemoryCgroup | None:
    """The memory cgroup of a sandboxed worker.

    Args:
        options: its :class:`~hub_envs.isolation.options.IsolationOptions`.

    Returns:
        A new cgroup holding ``options.memory_mb``, or None where none can be made and no limit was asked for
        (:func:`require_sandbox` refused the other case and warned about this one).

    Raises:
        SandboxUnavailableError: the cgroup could not be made or its limit not set.
    """
    if isinstance(cgroup_home(), str) and options.memory_limit_mb is None:
        return None
    return MemoryCgroup(options.memory_mb)


# --- what this machine allows ---------------------------------------------------------------------

_PROBE = r"""
import ctypes, json, os, platform, resource
libc = ctypes.CDLL(None, use_errno=True)
out = {}
def tryit(name, fn):
    try:
        r = fn()
        out[name] = True if r in (0, None, True) else f"errno {ctypes.get_errno()} ({os.strerror(ctypes.get_errno())})"
    except Exception as e:
        out[name] = f"{type(e).__name__}: {e}"
out["root"] = os.geteuid() == 0
tryit("network namespace", lambda: libc.unshare(0x40000000))
tryit("mount namespace", lambda: libc.unshare(0x00020000))
tryit("pid namespace", lambda: libc.unshare(0x20000000))
tryit("private mounts", lambda: libc.mount(b"none", b"/", None, ctypes.c_ulong(16384 | (1 << 18)), None))
tryit("tmpfs mounts", lambda: libc.mount(b"tmpfs", b"/tmp", b"tmpfs", ctypes.c_ulong(0), b"size=1m"))
def pivot():
    number = {"x86_64": 155, "aarch64": 41, "riscv64": 41}.get(platform.machine())
    if number is None:
        return f"no pivot_root syscall number known for {platform.machine()}"
    pid = os.fork()
    if pid == 0:  # a child in a mount namespace of its own: pivot_root moves every process of its namespace
        ok = libc.unshare(0x00020000) == 0 and libc.mount(b"none", b"/", None, ctypes.c_ulong(16384 | (1 << 18)), None) == 0
        ok = ok and libc.mount(b"tmpfs", b"/tmp", b"tmpfs", ctypes.c_ulong(0), b"size=1m") == 0
        ok = ok and (os.mkdir("/tmp/old") or True) and libc.syscall(ctypes.c_long(number), b"/tmp", b"/tmp/old") == 0
        os._exit(0 if ok else 1)
    return os.waitpid(pid, 0)[1] == 0 or "pivot_root failed"
tryit("pivot_root", pivot)
tryit("read-only bind mounts", lambda: libc.mount(b"/tmp", b"/tmp", None, ctypes.c_ulong(4096), None) or libc.mount(None, b"/tmp", None, ctypes.c_ulong(32 | 4096 | 1), None))
tryit("resource limits", lambda: resource.setrlimit(resource.RLIMIT_NPROC, (64, 64)))
tryit("no_new_privs", lambda: libc.prctl(38, 1, 0, 0, 0))
def drop():
    os.setgroups([]); os.setresgid(65534, 65534, 65534); os.setresuid(65534, 65534, 65534)
    caps = [l for l in open("/proc/self/status") if l.startswith("CapEff")][0].split()[1]
    return int(caps, 16) == 0
tryit("unprivileged uid (65534, no capabilities)", drop)
try:
    out["landlock"] = "landlock" in open("/sys/kernel/security/lsm").read()
except OSError:
    out["landlock"] = False
out["seccomp"] = [l.split()[1] for l in open("/proc/self/status") if l.startswith("Seccomp:")][0]
print(json.dumps(out))
"""

_SUPPORT: dict[str, Any] | None = None
REQUIRED = (
    "network namespace",
    "mount namespace",
    "pid namespace",
    "private mounts",
    "tmpfs mounts",
    "pivot_root",
    "read-only bind mounts",
    "resource limits",
    "no_new_privs",
    "unprivileged uid (65534, no capabilities)",
)
_WARNED_MEMORY = False


def sandbox_support(refresh: bool = False) -> dict[str, Any]:
    """What this machine allows a sandbox, probed once per process in a throwaway child.

    Args:
        refresh: probe again.

    Returns:
        ``{mechanism: True | why not}`` (``"memory cgroup"``: whether a sandbox's memory limit can cover all its
        processes together).
    """
    global _SUPPORT
    if _SUPPORT is None or refresh:
        try:
            proc = subprocess.run([sys.executable, "-S", "-c", _PROBE], capture_output=True, text=True, timeout=30)
            _SUPPORT = json.loads(proc.stdout.strip().splitlines()[-1])
        except Exception as e:  # the probe itself failed: nothing is known to work
            _SUPPORT = {"probe": f"failed: {e}"}
        home = cgroup_home(refresh=refresh)
        _SUPPORT["memory cgroup"] = True if isinstance(home, tuple) else home
    return dict(_SUPPORT)


def require_sandbox(memory_mb: int | None = None) -> dict[str, Any]:
    """Raise :class:`SandboxUnavailableError` naming every mechanism this machine does not allow.

    Args:
        memory_mb: the memory limit the caller asked for (``sandbox_limits={"memory_mb": ...}``), None for the
            default. One that cannot cover the whole sandbox (no memory cgroup here) is refused; the default
            then covers each process alone, and a :class:`~hub_envs.errors.HubEnvsWarning` says so once.

    Returns:
        :func:`sandbox_support`'s answer.

    Raises:
        SandboxUnavailableError: a mechanism is missing, or the memory limit asked for cannot be enforced.
    """
    global _WARNED_MEMORY
    support = sandbox_support()
    if not support.get("root"):
        raise SandboxUnavailableError(
            "sandbox=True needs root here (as in a container): the variant built on unprivileged user namespaces is not "
            "implemented yet, and a sandbox missing a part is never started. Run as root, or use isolation='process' "
            "(a worker process without the sandbox) for code you trust."
        )
    missing = {k: support.get(k, "not probed") for k in REQUIRED if support.get(k) is not True}
    if missing:
        raise SandboxUnavailableError(
            "sandbox=True: this machine does not allow "
            + "; ".join(f"{k} ({v})" for k, v in missing.items())
            + ". The env was not started (a sandbox never runs with a part missing). Allow them (a container needs "
            "CAP_SYS_ADMIN, and no seccomp profile blocking unshare/mount), or use isolation='process' for code you trust."
        )
    cgroup = support.get("memory cgroup")
    if cgroup is not True and memory_mb is not None:
        raise SandboxUnavailableError(
            f"sandbox_limits={{'memory_mb': {memory_mb}}} asks for one memory limit on the whole sandbox, which takes a "
            f"memory cgroup, and none can be made here ({cgroup}). The env was not started. Run where one can be (as "
            f"root with cgroup v2's memory controller enabled for this process's cgroup or its parent, or v1's memory "
            f"hierarchy writable), or leave memory_mb out: each process is then held to 4096 MB on its own (RLIMIT_AS)."
        )
    if cgroup is not True and not _WARNED_MEMORY:
        _WARNED_MEMORY = True
        warnings.warn(
            f"sandbox=True: no memory cgroup can be made here ({cgroup}): the sandbox's default memory limit "
            f"(4096 MB) covers each of its processes on its own (RLIMIT_AS), not all of them together.",
            HubEnvsWarning,
            stacklevel=3,
        )
    return support


# --- what a sandbox shows -------------------------------------------------------------------------


def hidden_paths(environ: dict[str, str] | None = None) -> list[str]:
    """Folders (and files) a sandbox never shows, even inside a folder it does: the home folder, the temp
    folders, the Hugging Face home, cache and token (``HF_HOME``, ``HF_HUB_CACHE``, ``HF_TOKEN_PATH``...) and
    ``HUB_ENVS_HOME``; each is replaced by an empty tmpfs (a file, by an empty file).

    Args:
        environ: the environment to read them from (default ``os.environ``).

    Returns:
        Their real paths, sorted.
    """
    environ = os.environ if environ is None else environ
    from hub_envs.paths import hub_envs_home

    home = os.path.expanduser("~")
    cache = environ.get("XDG_CACHE_HOME") or os.path.join(home, ".cache")
    paths = [home, "/tmp", "/var/tmp", "/dev/shm", os.path.join(cache, "huggingface"), str(hub_envs_home())]
    paths += [environ[k] for k in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME") if environ.get(k)]
    paths += [v for k, v in environ.items() if k.startswith("HF_") and v.startswith(("/", "~")) and "://" not in v]
    try:  # what huggingface_hub read when it was imported, if the environment changed since
        from huggingface_hub import constants

        paths += [str(getattr(constants, k)) for k in ("HF_HOME", "HF_HUB_CACHE", "HF_TOKEN_PATH") if getattr(constants, k, None)]
    except ImportError:
        pass
    return sorted({os.path.realpath(os.path.expanduser(p)) for p in paths} - {"/"})


def _module_name(entry: str) -> str:
    return entry.split(".", 1)[0] if entry.endswith((".py", ".so", ".pyd")) else entry


def needed_import_names(requirements: Any) -> set[str]:
    """The top-level import names of the installed distributions an env needs: its requirements, what the
    worker imports (numpy, gymnasium, msgpack) and their dependencies, as ``importlib.metadata`` records them.

    Args:
        requirements: the env's requirement strings (one that is not installed or not valid is skipped).

    Returns:
        The import names, ``hub_envs`` included.

    >>> "numpy" in needed_import_names([]) and "hub_envs" in needed_import_names([])
    True
    """
    from importlib.metadata import PackageNotFoundError, distribution

    from packaging.requirements import InvalidRequirement, Requirement
    from packaging.utils import canonicalize_name

    todo, dists, found = [*requirements, "numpy", "gymnasium", "msgpack"], set(), {"hub_envs"}
    while todo:
        try:
            req = Requirement(todo.pop())
        except InvalidRequirement:
            continue
        if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in ("", *req.extras)):
            continue
        name = canonicalize_name(req.name)
        if name in dists:
            continue
        try:
            dist = distribution(name)
        except PackageNotFoundError:
            continue
        dists.add(name)
        found |= _top_level(dist)
        todo += [r for r in dist.requires or [] if "extra ==" not in r] + [
            r for r in dist.requires or [] for e in req.extras if f'extra == "{e}"' in r
        ]
    return found


def _top_level(dist) -> set[str]:
    """The top-level names a distribution installs (its ``top_level.txt``, else the first part of its files)."""
    text = dist.read_text("top_level.txt")
    if text:
        return set(text.split())
    names = set()
    for file in dist.files or []:
        first = file.parts[0]
        if not first.endswith((".dist-info", ".egg-info", ".data")) and first not in ("..", "__pycache__"):
            names.add(_module_name(first))
    return names


_NEEDED: dict[tuple[str, ...], set[str]] = {}


def _installation(prefix: str, hidden: list[str]) -> list[str]:
    """The folders of a Python installation at ``prefix`` a sandbox shows: all of it, or, when it holds a folder the
    sandbox hides (a Python installed with ``--prefix=$HOME``), only its ``bin`` and ``lib`` folders."""
    if not any(_under(h, prefix) for h in hidden):
        return [prefix]
    return [os.path.join(prefix, d) for d in ("bin", "lib", "lib64") if os.path.isdir(os.path.join(prefix, d))]


def python_folders(options: Any, requirements: Any = (), hidden: Any = ()) -> list[str]:
    """The folders a sandboxed worker needs to import the env: the interpreter's installation (and its stdlib and
    site folders, or the venv and the folder linking ``hub_envs``), and from every other ``sys.path`` folder only
    the package folders the env needs (:func:`needed_import_names`; never the folder itself: the calling script's
    ``.env``, data or notes stay out), and ``hub_envs``.

    Args:
        options: the :class:`~hub_envs.isolation.options.IsolationOptions` (``python``, ``pythonpath``).
        requirements: the env's requirement strings.
        hidden: :func:`hidden_paths` (an installation inside one shows only its ``bin`` and ``lib``).

    Returns:
        Their real paths, sorted.
    """
    hidden = list(hidden)
    package = str(PACKAGE_DIR)
    if options.python:  # isolation="venv": the venv, the interpreter it links to, the folder linking hub_envs
        venv = os.path.dirname(os.path.dirname(options.python))
        base = os.path.dirname(os.path.dirname(os.path.realpath(options.python)))
        found = [venv, *_installation(os.path.realpath(base), hidden), package]
        found += [options.pythonpath] if options.pythonpath else []
        return sorted({os.path.realpath(p) for p in found})
    prefixes = {os.path.realpath(p) for p in (sys.base_prefix, sys.base_exec_prefix, sys.prefix, sys.exec_prefix)}
    installs = {f for p in prefixes for f in _installation(p, hidden)}
    found = installs | {os.path.dirname(os.path.realpath(sys.executable)), package}
    entries = [p for p in sys.path if p and os.path.isdir(p)] if options.pythonpath is None else [options.pythonpath]
    wanted: set[str] | None = None
    for entry in entries:
        real = os.path.realpath(entry)
        if any(_under(real, p) for p in installs) or os.path.basename(real) in ("site-packages", "dist-packages"):
            found.add(real)
            continue
        try:
            names = os.listdir(real)
        except OSError:
            continue
        if wanted is None:  # read once per process and requirements
            wanted = _NEEDED.get(tuple(requirements)) or _NEEDED.setdefault(
                tuple(requirements), needed_import_names(requirements)
            )
        found.update(os.path.realpath(os.path.join(real, n)) for n in names if _module_name(n) in wanted)
    return sorted(found)


def sandbox_init(target: Any, options: Any, cgroup: MemoryCgroup | None = None) -> dict[str, Any]:
    """The sandbox part of a worker's init message: what :func:`enter_sandbox` builds the sandbox from.

    Args:
        target: the env's :class:`~hub_envs.isolation.proxy.EnvTarget` (its files' sha256, its requirements).
        options: the :class:`~hub_envs.isolation.options.IsolationOptions` (interpreter, limits).
        cgroup: the sandbox's memory cgroup (None: none could be made; ``RLIMIT_AS`` alone limits memory).

    Returns:
        Plain data: the files to copy and verify, the folders to show and hide, the limits.
    """
    hide = hidden_paths()
    return {
        "files": [list(f) for f in target.files],
        "system": [d for d in SYSTEM_DIRS if os.path.lexists(d)],
        "hide": hide,
        "needed": python_folders(options, getattr(target, "requirements", ()), hide),
        "memory_mb": int(options.memory_mb),
        "nofile": int(options.max_open_files),
        "nproc": int(options.max_processes),
        "cgroup": cgroup.watch() if cgroup is not None else None,
    }


# --- inside the worker ----------------------------------------------------------------------------


def boot(argv: list[str] | None = None) -> None:
    """A sandboxed worker's entry point, run as ``python -S -P -c "...boot()" <fd> <page> <wake>``.

    Until the sandbox is entered nothing runs but the standard library and hub-envs' own standard-library-only
    modules (this one, :mod:`~hub_envs.isolation.doorbell`, :mod:`~hub_envs.errors`): ``-S`` keeps the
    interpreter's ``site`` from running, so no ``.pth`` file or ``sitecustomize`` of ``site-packages`` (a venv's
    packages are the repo's choice) runs as root outside the sandbox. Once inside, ``site.main()`` sets up
    ``site-packages`` (its ``.pth`` files run there, confined) and the worker serves
    (:func:`hub_envs.isolation.worker.serve`). A sandbox that cannot be entered ends the worker with
    :data:`~hub_envs.isolation.lifetime.ENTER_FAILED_EXIT`, the reason on its stderr.

    Args:
        argv: the arguments after ``-c`` (default ``sys.argv[1:]``).
    """
    conn, bell, init = attach_to_parent(sys.argv[1:] if argv is None else argv)
    try:
        enter_sandbox(init)  # forks: the code below runs as pid 1 of a new pid namespace
    except BaseException as e:
        message = f"hub-envs sandbox: the worker could not enter its sandbox: {type(e).__name__}: {e}\n"
        os.write(2, message.encode("utf-8", "backslashreplace"))
        os._exit(ENTER_FAILED_EXIT)
    import site

    site.main()  # site-packages and its .pth files, inside the sandbox
    from hub_envs.isolation.worker import serve

    serve(conn, bell, init)
    os._exit(0)


def _mountpoints() -> list[tuple[str, set[str]]]:
    out = []
    with open("/proc/self/mountinfo") as f:
        for line in f:
            parts = line.split()
            out.append((parts[4].replace("\\040", " "), set(parts[5].split(","))))
    return out


def _readonly_everything() -> None:
    flag_bits = {"nosuid": MS_NOSUID, "nodev": MS_NODEV, "noexec": MS_NOEXEC}
    for mp, opts in sorted(_mountpoints(), key=lambda m: len(m[0])):
        if mp.startswith("/proc"):  # its own, mounted after
            continue
        keep = sum(bit for name, bit in flag_bits.items() if name in opts)
        try:
            _mount(None, mp, None, MS_REMOUNT | MS_BIND | MS_RDONLY | keep)
        except OSError as e:
            if e.errno in (2, 13):  # a mount point this namespace cannot see: nothing to make read-only
                continue
            raise


def _under(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def _read_code(src: Path, files: list[list[str]], where: str) -> dict[str, bytes]:
    """The env's files (the published data excepted), each checked against the manifest's sha256 again."""
    out = {}
    for rel, digest in files:
        if rel.startswith(_SKIP_PREFIXES):
            continue
        data = (src / rel).read_bytes()
        if hashlib.sha256(data).hexdigest() != digest:
            raise IntegrityError(f"{where}: {rel} changed since it was verified; the sandbox refused to run it.")
        out[rel] = data
    return out


def _oom_watch(watch: dict[str, Any] | None) -> tuple[int, int, int] | None:
    """``(fd to poll, its poll events, fd of the OOM counters)``: what wakes the supervisor when the sandbox's
    memory cgroup runs out of memory, opened before the sandbox's own root hides the cgroup's files."""
    if watch is None:
        return None
    import select

    if watch["version"] == 2:  # memory.events changes (kernfs notifies a poll with POLLPRI)
        fd = os.open(os.path.join(watch["path"], "memory.events"), os.O_RDONLY | os.O_CLOEXEC)
        return fd, select.POLLPRI, fd
    efd = os.eventfd(0, os.EFD_CLOEXEC)  # cgroup v1: an eventfd registered for the cgroup's OOM notifications
    control = os.open(os.path.join(watch["path"], "memory.oom_control"), os.O_RDONLY | os.O_CLOEXEC)
    _write(os.path.join(watch["path"], "cgroup.event_control"), f"{efd} {control}")
    return efd, select.POLLIN, control


def _supervise(pid: int, box: dict[str, Any], watch: tuple[int, int, int] | None) -> int:
    """Wait for the sandbox's pid 1 (``pid``); end the sandbox as soon as its memory cgroup runs out of memory
    (a process the env forked may be the one the kernel killed, the worker living on). Returns its wait status."""
    import select
    import signal
    import time

    poller = select.poll()
    try:
        pidfd = os.pidfd_open(pid)
        poller.register(pidfd, select.POLLIN)
    except (AttributeError, OSError):  # no pidfd (Linux < 5.3): look again every 0.2 s
        pidfd = None
    if watch is not None:
        poller.register(watch[0], watch[1])
    recheck_until = 0.0  # v1 signals an OOM before its kill is counted: look again a short while after one
    while True:
        soon = recheck_until > time.monotonic()
        ready = poller.poll(50 if soon else None if pidfd is not None else 200)
        done, status = os.waitpid(pid, os.WNOHANG)
        if watch is not None and any(fd == watch[0] for fd, _ in ready):
            recheck_until = time.monotonic() + 1.0
            if watch[1] == select.POLLIN:
                os.eventfd_read(watch[0])
        if watch is not None and breached(os.pread(watch[2], 4096, 0).decode()):  # reading re-arms kernfs' poll
            if not done:
                os.kill(pid, signal.SIGKILL)  # pid 1 of the namespace: the kernel ends every process in it
                os.waitpid(pid, 0)
            os.write(
                2,
                f"hub-envs sandbox: the env's processes together went over the sandbox's memory limit "
                f"({box['cgroup']['limit_mb']} MB); the sandbox was stopped.\n".encode(),
            )
            os._exit(MEMORY_EXIT)
        if done:
            return status


def _pid_one(box: dict[str, Any]) -> None:
    """Fork so the env runs as pid 1 of the new pid namespace; this process supervises it (its memory cgroup)
    and passes its fate on."""
    import signal

    watch = _oom_watch(box.get("cgroup"))
    pid = os.fork()
    if pid == 0:
        for fd in {watch[0], watch[2]} if watch is not None else ():
            os.close(fd)
        set_parent_death_signal()
        return
    keep = {watch[0], watch[2]} if watch is not None else set()
    for fd in range(3, 1024):  # the outer process keeps nothing open: the parent sees EOF when the inner dies
        if fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass
    import resource

    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    try:  # the kernel picks the env's processes, never the supervisor, when the sandbox runs out of memory
        _write("/proc/self/oom_score_adj", "-1000")
    except OSError:
        pass
    status = _supervise(pid, box, watch)
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), sig)
    os._exit(os.WEXITSTATUS(status) if os.WIFEXITED(status) else 1)


def _deepest_is_bind(path: str, binds: list[str], tmpfs: list[str]) -> bool:
    """Whether ``path`` is shown by a bind of the host's folder (not hidden by a tmpfs mounted deeper)."""
    mounts = [(len(b), True) for b in binds if _under(path, b)] + [(len(t), False) for t in tmpfs if _under(path, t)]
    return bool(mounts) and max(mounts)[1]


def enter_sandbox(init: dict[str, Any]) -> None:
    """Confine this worker (see ``docs/isolation.md``). On return it runs as pid 1 of its pid namespace, uid 65534,
    and ``init["path"]`` points to the verified read-only copy of the env's code.

    Args:
        init: the parent's init message; its ``sandbox`` part is :func:`sandbox_init`'s.

    Raises:
        IntegrityError: a file of the env's code changed since it was verified.
        SandboxUnavailableError: the worker still holds privileges after dropping them.
        OSError: a mount, namespace or limit was refused (the worker then exits, nothing of the env ran).
    """
    import resource

    box = init["sandbox"]
    _pid_one(box)
    _mount("none", "/", None, MS_REC | MS_PRIVATE)
    code = _read_code(Path(init["path"]), box["files"], init["where"])  # verified before anything is hidden
    # what the new root shows, opened now (a needed folder may sit where the new root is built, or be hidden)
    links = {d: os.readlink(d) for d in box["system"] if os.path.islink(d)}
    system = [d for d in box["system"] if d not in links and os.path.isdir(d)]
    fds = {p: os.open(p, os.O_PATH | os.O_DIRECTORY) for p in dict.fromkeys(system + box["needed"]) if os.path.isdir(p)}
    new = os.path.realpath(SANDBOX_TMP)  # the new root is built on a tmpfs mounted here (in this namespace only)
    _mount("tmpfs", new, "tmpfs", MS_NOSUID | MS_NODEV, "size=4m,mode=755")
    for d, target in links.items():
        os.symlink(target, new + d)
    # shortest paths first, so each decision sees the mounts above it: a system folder is bound; a hidden path
    # gets an empty tmpfs (a file: an empty file) where a bind shows it; a needed folder is bound where it is not
    # shown as it is on the host (in the new root, or under a tmpfs that hides what holds it)
    binds: list[str] = []
    tmpfs: list[str] = []
    steps = [(d, "system") for d in system] + [(h, "hide") for h in box["hide"]] + [(p, "needed") for p in box["needed"]]
    for path, kind in sorted(steps, key=lambda step: (len(step[0]), step[1] != "needed")):
        shown = _deepest_is_bind(path, binds, tmpfs)
        if kind == "system" or (kind == "needed" and path in fds and not shown):
            os.makedirs(new + path, exist_ok=True)  # in a tmpfs: the new root, or one that hides a folder
            _mount(f"/proc/self/fd/{fds[path]}", new + path, None, MS_BIND | MS_REC)
            binds.append(path)
        elif kind == "hide" and path == SANDBOX_TMP:  # the private /tmp, always there
            os.makedirs(new + path, exist_ok=True)
            _mount("tmpfs", new + path, "tmpfs", MS_NOSUID | MS_NODEV, "size=512m,mode=1777")
            tmpfs.append(path)
        elif kind == "hide" and shown and os.path.isdir(new + path):
            _mount("tmpfs", new + path, "tmpfs", MS_NOSUID | MS_NODEV, "size=16m,mode=755")
            tmpfs.append(path)
        elif kind == "hide" and shown and os.path.lexists(new + path):
            empty = new + "/.empty"
            open(empty, "w").close()
            _mount(empty, new + path, None, MS_BIND)
    for fd in fds.values():
        os.close(fd)
    os.makedirs(new + "/proc", exist_ok=True)
    os.makedirs(new + "/.old-root", exist_ok=True)
    _pivot_root(new, new + "/.old-root")
    os.chdir("/")
    # MNT_DETACH: the host's file system is gone from this namespace
    _check(_libc().umount2(b"/.old-root", 2), "umount /.old-root")
    os.rmdir("/.old-root")
    _mount("proc", "/proc", "proc", MS_NOSUID | MS_NODEV | MS_NOEXEC)  # this pid namespace only
    for d in (ENV_DIR, HOME_DIR, WORK_DIR):
        os.makedirs(d, exist_ok=True)
    for rel, data in code.items():
        out = Path(ENV_DIR) / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    _mount(ENV_DIR, ENV_DIR, None, MS_BIND)
    _readonly_everything()  # every mount read-only, the private /tmp excepted (made writable again below)
    _mount(None, SANDBOX_TMP, None, MS_REMOUNT | MS_BIND | MS_NOSUID | MS_NODEV)
    _mount(None, ENV_DIR, None, MS_REMOUNT | MS_BIND | MS_RDONLY | MS_NOSUID | MS_NODEV)
    for d in (HOME_DIR, WORK_DIR):
        os.chown(d, NOBODY, NOBODY)
    # limits, then drop every privilege for good
    mem = box["memory_mb"] * 2**20
    resource.setrlimit(resource.RLIMIT_AS, (mem, mem))
    resource.setrlimit(resource.RLIMIT_NOFILE, (box["nofile"], box["nofile"]))
    resource.setrlimit(resource.RLIMIT_NPROC, (box["nproc"], box["nproc"]))
    resource.setrlimit(resource.RLIMIT_FSIZE, (512 * 2**20, 512 * 2**20))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    _check(_libc().prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "prctl(PR_SET_NO_NEW_PRIVS)")
    os.setgroups([])
    os.setresgid(NOBODY, NOBODY, NOBODY)
    os.setresuid(NOBODY, NOBODY, NOBODY)
    with open("/proc/self/status") as f:
        caps = next(line for line in f if line.startswith("CapEff:")).split()[1]
    if int(caps, 16) != 0 or os.getuid() != NOBODY:  # fail closed
        raise SandboxUnavailableError(f"the sandboxed worker still holds privileges (uid {os.getuid()}, CapEff {caps}).")
    set_parent_death_signal()  # setuid clears the parent-death signal: arm it again
    os.chdir(WORK_DIR)
    init["path"] = ENV_DIR
