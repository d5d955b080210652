"""``isolation="venv"``: the worker runs in a venv built with uv from the env's own requirements, one per
requirements digest, built atomically and once, reused offline once cached (``docs/isolation.md``).

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
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from hub_envs._text import safe_lines, safe_text
from hub_envs.errors import IsolationUnavailableError, VenvBuildError
from hub_envs.paths import PACKAGE_DIR, hub_envs_home

RECORD = "hub-envs-venv.json"
WORKER_NEEDS = ("numpy", "gymnasium")
#: what hub-envs' own worker code needs (the wire of its answers): installed too, never pinned to a publisher's
WIRE_NEEDS = ("msgpack>=1.0",)
#: the caller's environment variables uv (and a build backend it starts) may see while a venv is built: where
#: things live, locale, proxies and certificates, uv's own settings (``UV_*``, ``LC_*``); every other variable,
#: ``HF_TOKEN`` and every other token or key included, is left out
BUILD_ENV = (
    "PATH",
    "HOME",
    "USER",
    "LOGNAME",
    "LANG",
    "LANGUAGE",
    "TZ",
    "TMPDIR",
    "XDG_CACHE_HOME",
    "XDG_CONFIG_HOME",
    "XDG_DATA_HOME",
    "SSL_CERT_FILE",
    "SSL_CERT_DIR",
    "HTTP_PROXY",
    "HTTPS_PROXY",
    "NO_PROXY",
    "ALL_PROXY",
    "http_proxy",
    "https_proxy",
    "no_proxy",
    "all_proxy",
)
BUILD_ENV_PREFIXES = ("UV_", "LC_")
_NAME_RE = re.compile(r"^([A-Z0-9]|[A-Z0-9][A-Z0-9._-]*[A-Z0-9])$", re.IGNORECASE)  # PEP 508's project name


def venvs_root() -> Path:
    """The folder holding the venvs: ``$HUB_ENVS_HOME/venvs``."""
    return hub_envs_home() / "venvs"


def venv_digest(requirements: Any, python_minor: str, constraints: Any = ()) -> str:
    """The name of the venv for these requirements (order and repeats do not matter).

    Args:
        requirements: requirement strings.
        python_minor: the Python ``major.minor`` the venv is made for.
        constraints: uv constraints (``versions="publisher"``'s dependency closure).

    Returns:
        20 hex digits of a sha256 over them and the worker's own needs.
    """
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
    """The interpreter of a venv.

    Args:
        venv: the venv's folder.
    """
    return venv / "bin" / "python"


def hub_envs_path() -> str:
    """A folder holding only a link to this hub-envs package: the PYTHONPATH of a venv worker."""
    package = PACKAGE_DIR
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


def _refused(where: str, what: str, why: str) -> VenvBuildError:
    return VenvBuildError(
        f"{where}: isolation='venv' refused {what}: {why}. Nothing was installed and no code of the repo ran. "
        f"Ask the publisher to depend on released packages by name (e.g. 'pybullet>=3.2'), or load it without "
        f"isolation='venv' after reading it."
    )


def _name(name, field: str, where: str) -> str:
    """A package name from a manifest, canonical, or the refusal (it is written into uv's constraints)."""
    from packaging.utils import canonicalize_name

    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise _refused(where, f"{field} entry {safe_text(repr(name))}", "it is not a package name")
    return canonicalize_name(name)


def _version(version, field: str, where: str) -> str:
    """A version from a manifest, normalised, or the refusal (it becomes an ``==`` pin)."""
    from packaging.version import InvalidVersion, Version

    try:
        return str(Version(version))
    except (InvalidVersion, TypeError):
        raise _refused(where, f"{field} = {safe_text(repr(version))}", "it is not a version") from None


def checked_requirements(requirements, *, where: str, constraints: bool = False) -> list[str]:
    """The requirements (or, ``constraints=True``, the ``name==version`` constraints) as uv is given them: each
    parsed and written back in its canonical form, none a direct reference (``name @ URL``: uv would fetch and
    build whatever the URL names, a local path included), each constraint a plain pin.

    Args:
        requirements: requirement strings, from the env's manifest.
        where: ``repo@sha``, for the message.
        constraints: check ``name==version`` pins (no extras, no markers, no other operator).

    Returns:
        The requirements, each ``str(packaging.requirements.Requirement(text))``.

    Raises:
        VenvBuildError: naming the refused requirement, with nothing installed.
    """
    from packaging.requirements import InvalidRequirement, Requirement

    out = []
    for text in requirements:
        try:
            req = Requirement(text)
        except (InvalidRequirement, TypeError) as e:
            raise _refused(where, f"the requirement {safe_text(repr(text))}", f"it is not a valid requirement ({e})") from None
        if req.url:
            raise _refused(
                where,
                f"the requirement {safe_text(repr(text))}",
                "it is a direct reference (name @ URL): installing it would fetch and build what the URL names, "
                "running the repo's choice of code as you before any sandbox exists",
            )
        if constraints and (req.extras or req.marker or len(req.specifier) != 1 or next(iter(req.specifier)).operator != "=="):
            raise _refused(where, f"the constraint {safe_text(repr(text))}", "a constraint must be name==version")
        out.append(str(req))
    return out


def publisher_pins(
    requirements, versions: dict[str, str], resolved: dict[str, str] | None = None, *, where: str = "the env"
) -> tuple[list[str], list[str], str | None, str | None, list[str]]:
    """What ``versions="publisher"`` builds: the publisher's recorded versions pinned.

    Args:
        requirements: the env's requirement strings.
        versions: the manifest's ``versions`` (package -> version, and ``python``).
        resolved: the manifest's ``resolved`` dependency closure (format 3; None: older).
        where: repo@sha, to name in errors and notes.

    Returns:
        ``(pinned requirements, uv constraints, interpreter or None, its minor or None, notes)``.

    Raises:
        VenvBuildError: a recorded version that is not a version, a ``resolved`` name that is not a package name.
    """
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
            version = _version(version, f"hub_env.json versions[{req.name!r}]", where)
            extras = f"[{','.join(sorted(req.extras))}]" if req.extras else ""
            marker = f"; {req.marker}" if req.marker else ""
            pinned.append(f"{req.name}{extras}=={version}{marker}")
        else:
            pinned.append(text)
            notes.append(f"{req.name}: the publisher recorded no version; the newest compatible was installed")
    # the wire's own needs are hub-envs' here, never the publisher's: not held to a recorded version either
    pinned_names = {canonicalize_name(n) for n in names} | {canonicalize_name(Requirement(w).name) for w in WIRE_NEEDS}
    constraints = [
        f"{_name(name, 'hub_env.json resolved', where)}=={_version(version, f'hub_env.json resolved[{name!r}]', where)}"
        for name, version in sorted((resolved or {}).items())
        if name not in pinned_names
    ]
    if not resolved:
        notes.append(
            "the manifest records no dependency closure (published before hub-envs format 3): dependencies of the "
            "requirements resolved to the newest compatible"
        )
    python, minor = None, None
    published = versions.get("python")
    if published:
        if not isinstance(published, str) or not re.fullmatch(r"\d+\.\d+(\.\d+)?\S{0,16}", published):  # a uv argument
            raise _refused(where, f"hub_env.json versions['python'] = {safe_text(repr(published))}", "it is not a Python version")
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


def build_environ(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The environment uv runs in while it builds a venv: :data:`BUILD_ENV` and ``UV_*`` / ``LC_*`` only.

    Args:
        environ: the caller's environment (default ``os.environ``).

    >>> sorted(build_environ({"HF_TOKEN": "hf_x", "AWS_SECRET_ACCESS_KEY": "k", "PATH": "/usr/bin", "UV_CACHE_DIR": "/c"}))
    ['PATH', 'UV_CACHE_DIR']
    """
    environ = os.environ if environ is None else environ
    return {k: v for k, v in environ.items() if k in BUILD_ENV or k.startswith(BUILD_ENV_PREFIXES)}


def _site_packages(venv: Path) -> list[Path]:
    return sorted(venv.glob("lib/python*/site-packages"))


def _installed(venv: Path) -> list[str]:
    """``name==version`` of every distribution in the venv, read from its metadata files (the venv is not run)."""
    from importlib.metadata import distributions

    from packaging.utils import canonicalize_name

    out = set()
    for dist in distributions(path=[str(p) for p in _site_packages(venv)]):
        name = dist.metadata["Name"]
        if name:
            out.add(f"{canonicalize_name(name)}=={dist.version}")
    return sorted(out)


def venv_for(
    requirements,
    *,
    where: str,
    python: str | None = None,
    minor: str | None = None,
    constraints=(),
    wheels_only: bool = False,
) -> tuple[Path, dict]:
    """The venv for ``requirements`` (built if missing), holding ``constraints`` (``name==version`` of packages
    the requirements may pull in): ``(folder, record)``. See the module docstring.

    Args:
        requirements: the env's requirement strings (checked: :func:`checked_requirements`).
        where: ``repo@sha``, for messages.
        python: the interpreter to build it on (default: this one); ``minor`` its ``X.Y``.
        constraints: ``name==version`` pins of the requirements' dependencies (``versions="publisher"``).
        wheels_only: install wheels only, never build a package from source (a sandboxed env: a build would
            run the package's code outside the sandbox). A venv already built for the same digest is reused.

    Returns:
        ``(venv folder, its record)``: the record's ``installed`` lists what the venv holds.

    Raises:
        VenvBuildError: a requirement was refused, or uv could not build the venv (its message is included).
    """
    python = python or sys.executable
    minor = minor or f"{sys.version_info[0]}.{sys.version_info[1]}"
    checked = checked_requirements(requirements, where=where)
    checked_constraints = checked_requirements(constraints, where=where, constraints=True)
    reqs = sorted(set(checked) | set(WORKER_NEEDS) | set(WIRE_NEEDS))
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
            env = build_environ()
            constrain: list[str] = []
            if checked_constraints:
                (tmp / "constraints.txt").write_text("".join(f"{c}\n" for c in sorted(set(checked_constraints))))
                constrain = ["--constraint", str(tmp / "constraints.txt")]
            venv_python_path = tmp / "venv" / "bin" / "python"
            for cmd in (
                [*uv, "venv", "--quiet", "--python", python, str(tmp / "venv")],
                [*uv, "pip", "install", "--quiet", "--python", str(venv_python_path)]
                + (["--no-build"] if wheels_only else [])
                + [*constrain, *reqs],
            ):
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp)
                if proc.returncode != 0:
                    hint = (
                        " In a sandbox, only wheels are installed (building a package from source runs its code, "
                        "outside the sandbox): a package above has no wheel for this Python. If you trust it, build it "
                        "once yourself (`uv pip install <package>`: uv keeps the wheel in its cache and reuses it here)."
                        if wheels_only
                        else ""
                    )
                    raise VenvBuildError(
                        f"{where}: building its venv failed ({' '.join(cmd[len(uv) : len(uv) + 2])}); uv says:\n"
                        f"{safe_lines((proc.stderr or proc.stdout).strip())}\n"
                        f"Nothing was left behind.{hint} Fix the repo's requirements "
                        f"({', '.join(safe_text(r) for r in requirements) or 'none'}) or use isolation='process'."
                    )
            # bytecode at build time: a sandboxed worker sees the venv read-only, and with PYTHONDONTWRITEBYTECODE
            # every worker would compile numpy, gymnasium and the simulator again at each start. Compiled here with
            # -S -I, not by uv (which starts the venv's python with its site: a wheel's .pth file would run here,
            # outside any sandbox); a file that does not compile is left as it is (compileall's exit code ignored).
            for site in _site_packages(tmp / "venv"):
                subprocess.run(
                    [str(venv_python_path), "-S", "-I", "-m", "compileall", "-q", "-j", "0", str(site)],
                    capture_output=True,
                    env=env,
                    cwd=tmp,
                )
            version = subprocess.run(
                [str(venv_python_path), "-S", "-I", "-c", "import platform; print(platform.python_version())"],
                capture_output=True,
                text=True,
                env=env,
                cwd=tmp,
            ).stdout.strip()
            record = {
                "digest": digest,
                "python": version or minor,
                "requirements": list(requirements),
                "constraints": sorted(set(constraints)),
                "installed": _installed(tmp / "venv"),
                "wheels_only": wheels_only,
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
