"""``isolation="venv"``: the worker runs in a venv built from the env's own requirements.

One venv per digest of (Python minor version, the env's requirements, the worker's own needs ``numpy`` and
``gymnasium``, and ``msgpack`` for its answers), under ``$HUB_ENVS_HOME/venvs/<digest>``, built with uv:

* **atomically**: built in a temporary folder next to it and renamed into place only when complete, with
  a ``hub-envs-venv.json`` record; a build that fails (uv cannot resolve or install) is removed and raises
  :class:`~hub_envs.errors.VenvBuildError` with uv's own message;
* **once**: under an exclusive file lock (``fcntl.flock`` on ``<digest>.lock``), so concurrent loaders (threads
  or processes) build it once and the others wait, then reuse it;
* **offline once cached**: a complete venv is reused without running uv at all.

The venv holds the env's requirements, numpy, gymnasium and msgpack (its answers' wire), not torch or lerobot (an env module that
imports lerobot must list it, and keeping the config in its own module keeps the venv small: see
``envs/pendulum``). hub-envs itself is not installed into it: the worker imports the parent's hub-envs
through a folder that holds only a link to the ``hub_envs`` package (no other package of the parent leaks
in).

``versions="publisher"`` (:func:`publisher_pins`) pins every package the manifest records a version of
(``hub_env.json`` ``versions``: numpy, gymnasium and each requirement's package, the simulator included) to
that version, holds the rest of the requirements' dependency closure to the versions the publisher had
(``resolved``, format 3: uv constraints, so a dependency that is not needed here is not installed), and
uses the publisher's Python minor when an interpreter of it is found (``uv python find``), else this one
with a note. A manifest of format 1 or 2 has no ``resolved``: dependencies of dependencies then resolve to
the newest compatible, and the notes say so. What the venv really holds is in its record (``installed``),
which the reproduce report shows as the worker's versions.

Example:
    >>> from hub_envs.isolation.venvs import venv_digest
    >>> venv_digest(["gymnasium>=1.1", "numpy>=1.26"], "3.13") == venv_digest(["numpy>=1.26", "gymnasium>=1.1"], "3.13")
    True
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hub_envs.errors import IsolationUnavailableError, VenvBuildError
from hub_envs.paths import hub_envs_home

RECORD = "hub-envs-venv.json"
WORKER_NEEDS = ("numpy", "gymnasium")
#: what hub-envs' own worker code needs (the wire of its answers): installed too, never pinned to a publisher's
WIRE_NEEDS = ("msgpack>=1.0",)


def venvs_root() -> Path:
    return hub_envs_home() / "venvs"


def venv_digest(requirements, python_minor: str, constraints=()) -> str:
    data = {"python": python_minor, "requirements": sorted(set(requirements)), "worker": list(WORKER_NEEDS + WIRE_NEEDS)}
    if constraints:
        data["constraints"] = sorted(set(constraints))
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:20]


def _uv() -> list[str]:
    try:
        from uv import find_uv_bin

        return [find_uv_bin()]
    except Exception:
        found = shutil.which("uv")
        if found:
            return [found]
    raise IsolationUnavailableError(
        "isolation='venv' builds the env's venv with uv, which is not installed here: pip install uv (or put uv on PATH)."
    )


def venv_python(venv: Path) -> Path:
    return venv / "bin" / "python"


def hub_envs_path() -> str:
    """A folder holding only a link to this hub-envs package: the PYTHONPATH of a venv worker."""
    import hub_envs

    package = Path(hub_envs.__file__).resolve().parent
    folder = venvs_root() / "_hub_envs" / hashlib.sha256(str(package).encode()).hexdigest()[:16]
    link = folder / "hub_envs"
    if not link.is_symlink():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".hub_envs-{os.getpid()}"
        try:
            os.symlink(package, tmp)
            os.replace(tmp, link)
        finally:
            if tmp.is_symlink():
                tmp.unlink()
    return str(folder)


def publisher_pins(
    requirements, versions: dict[str, str], resolved: dict[str, str] | None = None
) -> tuple[list[str], list[str], str | None, str | None, list[str]]:
    """``(pinned requirements, constraints, interpreter, its minor, notes)`` for ``versions="publisher"``."""
    from packaging.requirements import InvalidRequirement, Requirement
    from packaging.utils import canonicalize_name

    pinned, notes = [], []
    names = []
    for text in list(requirements) + list(WORKER_NEEDS):
        try:
            req = Requirement(text)
        except InvalidRequirement:
            pinned.append(text)
            continue
        if req.name in names:
            continue
        names.append(req.name)
        version = versions.get(req.name)
        if version and version != "not installed":
            extras = f"[{','.join(sorted(req.extras))}]" if req.extras else ""
            marker = f"; {req.marker}" if req.marker else ""
            pinned.append(f"{req.name}{extras}=={version}{marker}")
        else:
            pinned.append(text)
            notes.append(f"{req.name}: the publisher recorded no version; the newest compatible was installed")
    # the wire's own needs are hub-envs' here, never the publisher's: not held to a recorded version either
    pinned_names = {canonicalize_name(n) for n in names} | {canonicalize_name(Requirement(w).name) for w in WIRE_NEEDS}
    constraints = [f"{name}=={version}" for name, version in sorted((resolved or {}).items()) if name not in pinned_names]
    if not resolved:
        notes.append(
            "the manifest records no dependency closure (published before hub-envs format 3): dependencies of the "
            "requirements resolved to the newest compatible"
        )
    python, minor = None, None
    published = versions.get("python")
    if published:
        minor = ".".join(published.split(".")[:2])
        if minor != f"{sys.version_info[0]}.{sys.version_info[1]}":
            try:
                found = subprocess.run([*_uv(), "python", "find", minor], capture_output=True, text=True, timeout=60)
                python = found.stdout.strip() if found.returncode == 0 and found.stdout.strip() else None
            except (OSError, subprocess.TimeoutExpired):
                python = None
            if python is None:
                notes.append(
                    f"python {published} (the publisher's) is not installed here: the worker runs python "
                    f"{sys.version_info[0]}.{sys.version_info[1]}"
                )
                minor = None
    return pinned, constraints, python, minor, notes


def venv_for(
    requirements, *, where: str, python: str | None = None, minor: str | None = None, constraints=()
) -> tuple[Path, dict]:
    """The venv for ``requirements`` (built if missing), holding ``constraints`` (``name==version`` of packages
    the requirements may pull in): ``(folder, record)``. See the module docstring."""
    python = python or sys.executable
    minor = minor or f"{sys.version_info[0]}.{sys.version_info[1]}"
    reqs = sorted(set(requirements) | set(WORKER_NEEDS) | set(WIRE_NEEDS))
    digest = venv_digest(requirements, minor, constraints)
    root = venvs_root()
    final = root / digest
    record_path = final / RECORD
    if record_path.is_file():  # complete: reuse it, no uv, no network
        return final, json.loads(record_path.read_text())
    root.mkdir(parents=True, exist_ok=True)
    with open(root / f"{digest}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one builder; the others wait here and then find it built
        if record_path.is_file():
            return final, json.loads(record_path.read_text())
        tmp = Path(tempfile.mkdtemp(prefix=f".{digest}-", dir=root))
        t0 = time.perf_counter()
        try:
            uv = _uv()
            env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
            constrain: list[str] = []
            if constraints:
                (tmp / "constraints.txt").write_text("".join(f"{c}\n" for c in sorted(set(constraints))))
                constrain = ["--constraint", str(tmp / "constraints.txt")]
            for cmd in (
                [*uv, "venv", "--quiet", "--python", python, str(tmp / "venv")],
                # bytecode at build time: a sandboxed worker sees the venv read-only, and with PYTHONDONTWRITEBYTECODE
                # every worker would compile numpy, gymnasium and the simulator again at each start
                [*uv, "pip", "install", "--quiet", "--compile-bytecode", "--python", str(tmp / "venv" / "bin" / "python")]
                + [*constrain, *reqs],
            ):
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
                if proc.returncode != 0:
                    raise VenvBuildError(
                        f"{where}: building its venv failed ({' '.join(cmd[len(uv) : len(uv) + 2])}); uv says:\n"
                        f"{(proc.stderr or proc.stdout).strip()}\nNothing was left behind. Fix the repo's requirements "
                        f"({', '.join(requirements) or 'none'}) or use isolation='process'."
                    )
            freeze = subprocess.run(
                [*uv, "pip", "freeze", "--python", str(tmp / "venv" / "bin" / "python")], capture_output=True, text=True, env=env
            ).stdout.split()
            version = subprocess.run(
                [str(tmp / "venv" / "bin" / "python"), "-c", "import platform; print(platform.python_version())"],
                capture_output=True,
                text=True,
            ).stdout.strip()
            record = {
                "digest": digest,
                "python": version or minor,
                "requirements": list(requirements),
                "constraints": sorted(set(constraints)),
                "installed": freeze,
                "build_seconds": round(time.perf_counter() - t0, 2),
                "built_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            }
            (tmp / "venv" / RECORD).write_text(json.dumps(record, indent=2) + "\n")
            os.rename(tmp / "venv", final)  # atomic: a venv is there complete, or not at all
            with open(root / "builds.log", "a") as log:
                log.write(f"{digest} {os.getpid()} {record['build_seconds']}\n")
            return final, record
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
