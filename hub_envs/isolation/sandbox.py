"""``sandbox=True``: an isolated env's worker, confined with the kernel's own mechanisms.

What a sandboxed worker gets (each part is checked, and a machine that does not allow one gets a
:class:`~hub_envs.errors.SandboxUnavailableError` naming it: never a sandbox with a part silently missing):

* **no network**: a new network namespace (only a loopback interface, down): no TCP, not even to 127.0.0.1;
* **its own process tree**: a new pid namespace whose init is the worker; when it ends (or the parent kills
  it, or the parent dies: ``PR_SET_PDEATHSIG``) the kernel ends everything the env's code started;
* **a read-only view of the files**: a new mount namespace in which every mount is read-only; the user's
  home, ``/tmp``, ``/var/tmp`` and ``/dev/shm`` are replaced by empty private tmpfs (the Python installation
  and ``sys.path`` folders that live there are bound back read-only); the env's code is a private copy,
  verified again against the manifest's sha256 and mounted read-only; the only writable place is a private
  ``/tmp`` (also ``HOME``), which disappears with the worker; a fresh ``/proc`` shows only the sandbox;
* **no privileges**: it drops to uid/gid 65534 (nobody) with no capabilities and ``PR_SET_NO_NEW_PRIVS``
  (so it can neither undo the mounts nor regain anything through a setuid binary);
* **no secrets**: the environment is rebuilt from an allow-list (``PATH``, locale, thread counts):
  ``HF_TOKEN`` and every other variable is gone, ``HOME`` and ``TMPDIR`` point into the private ``/tmp``;
* **resource limits**: ``RLIMIT_AS`` (memory), ``RLIMIT_NOFILE``, ``RLIMIT_NPROC`` (fork bombs: counted
  for uid 65534), ``RLIMIT_FSIZE``, no core files;
* **a watchdog on every call**: ``step_timeout`` (60 s unless given); a call that takes longer kills it.

The namespaces are made with ``unshare(2)`` through ``ctypes`` (Python 3.11 has no ``os.unshare``) in the
forked child before it executes the worker, and the rest by the worker itself before it imports the env's
code. This needs root (as here, in a container); without it, the unprivileged-user-namespace variant is not
implemented yet and ``sandbox=True`` is refused. Seccomp and Landlock are not used (the namespaces and the
uid drop cover network and files); :func:`sandbox_support` reports what this machine allows.

Example:
    >>> from hub_envs.isolation.sandbox import scrubbed_environ
    >>> sorted(scrubbed_environ({"HF_TOKEN": "hf_x", "AWS_SECRET_ACCESS_KEY": "k", "PATH": "/usr/bin"}, home=None))
    ['HOME', 'PATH', 'TMPDIR']
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from hub_envs.errors import IntegrityError, SandboxUnavailableError

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


def unshare(flags: int) -> None:
    _check(_libc().unshare(flags), f"unshare({flags:#x})")


def mount(source: str | None, target: str, fstype: str | None, flags: int, data: str | None = None) -> None:
    enc = lambda s: s.encode() if s is not None else None  # noqa: E731
    _check(_libc().mount(enc(source), enc(target), enc(fstype), ctypes.c_ulong(flags), enc(data)), f"mount {target}")


def umount(target: str) -> None:
    _check(_libc().umount2(target.encode(), 2), f"umount {target}")  # MNT_DETACH


def scrubbed_environ(environ: dict[str, str], *, home: Any) -> dict[str, str]:
    """The environment of a sandboxed worker: the allow-list only, ``HOME``/``TMPDIR`` in its private /tmp."""
    env = {k: v for k, v in environ.items() if k in ALLOWED_ENV or k.startswith("LC_")}
    env["HOME"] = HOME_DIR
    env["TMPDIR"] = SANDBOX_TMP
    return env


def unshare_namespaces() -> None:
    """``preexec_fn`` of a sandboxed worker: new mount, network and pid namespaces (the child, before exec)."""
    unshare(CLONE_NEWNS | CLONE_NEWNET | CLONE_NEWPID)


# --- what this machine allows ---------------------------------------------------------------------

_PROBE = r"""
import ctypes, json, os, resource
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
    "read-only bind mounts",
    "resource limits",
    "no_new_privs",
    "unprivileged uid (65534, no capabilities)",
)


def sandbox_support(refresh: bool = False) -> dict[str, Any]:
    """What this machine allows, probed once per process in a throwaway child: ``{mechanism: True | why not}``."""
    global _SUPPORT
    if _SUPPORT is None or refresh:
        try:
            proc = subprocess.run([sys.executable, "-S", "-c", _PROBE], capture_output=True, text=True, timeout=30)
            _SUPPORT = json.loads(proc.stdout.strip().splitlines()[-1])
        except Exception as e:  # the probe itself failed: nothing is known to work
            _SUPPORT = {"probe": f"failed: {e}"}
    return dict(_SUPPORT)


def require_sandbox() -> dict[str, Any]:
    """Raise :class:`SandboxUnavailableError` naming every mechanism this machine does not allow."""
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
    return support


def sandbox_init(target, options, scratch) -> dict[str, Any]:
    """The sandbox part of a worker's init message."""
    home = os.path.realpath(os.path.expanduser("~"))
    needed = [
        sys.base_prefix,
        sys.base_exec_prefix,
        sys.prefix,
        sys.exec_prefix,
        os.path.dirname(os.path.realpath(sys.executable)),
    ]
    needed += [p for p in sys.path if p and os.path.isdir(p)] if options.pythonpath is None else [options.pythonpath]
    if options.python:  # isolation="venv": the venv (its python links to a base interpreter, bound too)
        venv = os.path.dirname(os.path.dirname(options.python))
        base = os.path.dirname(os.path.dirname(os.path.realpath(options.python)))
        needed += [venv, base]
    if options.pythonpath:  # the folder with the link to hub_envs, and the package it links to
        import hub_envs

        needed.append(os.path.dirname(os.path.dirname(os.path.realpath(hub_envs.__file__))))
    return {
        "files": [list(f) for f in target.files],
        "hide": sorted({home, "/tmp", "/var/tmp", "/dev/shm"}),
        "needed": sorted({os.path.realpath(p) for p in needed}),
        "memory_mb": int(options.memory_limit_mb),
        "nofile": int(options.max_open_files),
        "nproc": int(options.max_processes),
    }


# --- inside the worker ----------------------------------------------------------------------------


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
        if mp.startswith("/proc") or mp.startswith("/sys"):
            continue
        keep = sum(bit for name, bit in flag_bits.items() if name in opts)
        try:
            mount(None, mp, None, MS_REMOUNT | MS_BIND | MS_RDONLY | keep)
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


def _pid_one() -> None:
    """Fork so the env runs as pid 1 of the new pid namespace; this process waits and passes its fate on."""
    import signal

    pid = os.fork()
    if pid == 0:
        from hub_envs.isolation.worker import set_parent_death_signal

        set_parent_death_signal()
        return
    for fd in range(3, 1024):  # the outer process keeps nothing open: the parent sees EOF when the inner dies
        try:
            os.close(fd)
        except OSError:
            pass
    import resource

    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        signal.signal(sig, signal.SIG_DFL)
        os.kill(os.getpid(), sig)
    os._exit(os.WEXITSTATUS(status) if os.WIFEXITED(status) else 1)


def enter_sandbox(init: dict[str, Any]) -> None:
    """Confine this worker (see the module docstring). On return it runs as pid 1 of its pid namespace, uid 65534,
    and ``init["path"]`` points to the verified read-only copy of the env's code."""
    import resource

    box = init["sandbox"]
    _pid_one()
    mount("none", "/", None, MS_REC | MS_PRIVATE)
    hidden = box["hide"]
    # what Python needs from where the sandbox hides things (home, /tmp): held open, bound back after hiding
    keep = {p: os.open(p, os.O_PATH | os.O_DIRECTORY) for p in box["needed"] if any(_under(p, h) for h in hidden)}
    code = _read_code(Path(init["path"]), box["files"], init["where"])  # verified before it is hidden
    for h in hidden:
        if os.path.isdir(h):
            opts = "size=512m,mode=1777" if h == SANDBOX_TMP else "size=16m,mode=755"
            mount("tmpfs", h, "tmpfs", MS_NOSUID | MS_NODEV, opts)
    for d in (ENV_DIR, HOME_DIR, WORK_DIR):
        os.makedirs(d, exist_ok=True)
    for rel, data in code.items():
        out = Path(ENV_DIR) / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data)
    mount(ENV_DIR, ENV_DIR, None, MS_BIND)
    for path, fd in keep.items():
        os.makedirs(path, exist_ok=True)
        mount(f"/proc/self/fd/{fd}", path, None, MS_BIND | MS_REC)
        os.close(fd)
    _readonly_everything()  # every mount read-only, the private /tmp excepted (made writable again below)
    mount(None, SANDBOX_TMP, None, MS_REMOUNT | MS_BIND | MS_NOSUID | MS_NODEV)
    mount(None, ENV_DIR, None, MS_REMOUNT | MS_BIND | MS_RDONLY | MS_NOSUID | MS_NODEV)
    mount("proc", "/proc", "proc", MS_NOSUID | MS_NODEV | MS_NOEXEC)  # this pid namespace only
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
    from hub_envs.isolation.worker import set_parent_death_signal

    set_parent_death_signal()  # setuid clears the parent-death signal: arm it again
    os.chdir(WORK_DIR)
    init["path"] = ENV_DIR
