"""Import an env's code from a folder, under a module name unique to that folder's identity.

An env repo is a flat folder of Python files (plus assets). It is imported as a synthetic package
whose ``__path__`` is the folder, named after repo + revision, so

* files import each other with relative imports (``from .physics import step``);
* two revisions of one repo live side by side in one process (``sys.modules`` never collides);
* nothing is added to ``sys.path``;
* only the ``.py`` sources are ever run: no ``__pycache__`` bytecode is read or written and no
  extension module (``.so``) is imported from the folder, so what runs is exactly the source the
  manifest hashes (a planted unchecked-hash ``.pyc`` would otherwise run instead of it), and a
  snapshot in the Hugging Face cache is never written to.

Example:
    >>> from hub_envs.importing import import_env_folder, resolve_entry_point
    >>> pkg = import_env_folder("envs/pendulum", key="local-pendulum")      # doctest: +SKIP
    >>> EnvCls = resolve_entry_point(pkg, "pendulum_env:PendulumEnv")       # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.machinery
import importlib.util
import marshal
import os
import re
import sys
import types
from pathlib import Path

from hub_envs.errors import EnvCodeError, InvalidRepoFormatError, RegistrationConflictError
from hub_envs.paths import hub_envs_home
from hub_envs.repo_format import DATASET_DIR, ENTRY_POINT_RE, IGNORED_PARTS, MEDIA_DIR

ROOT_PACKAGE = "hub_envs_code"
_ENTRY_POINT_RE = ENTRY_POINT_RE


def module_key(*parts: str) -> str:
    """A valid Python identifier built from ``parts`` (e.g. repo id and sha)."""
    raw = "__".join(parts)
    key = re.sub(r"\W", "_", raw)
    return key if not key[0].isdigit() else f"_{key}"


class _SourceLoader(importlib.machinery.SourceFileLoader):
    """Loads a module from its ``.py`` source only: never reads or writes ``__pycache__``.

    Compiled code is cached under ``$HUB_ENVS_HOME/bytecode``, keyed by a sha256 of the source
    bytes themselves (and path, Python magic number, optimization level), so a cache entry can only
    ever stand for exactly the source that was read; nothing is written if ``sys.dont_write_bytecode``.
    """

    def get_code(self, fullname):
        path = self.get_filename(fullname)
        source = self.get_data(path)
        key = hashlib.sha256(b"\0".join([importlib.util.MAGIC_NUMBER, str(sys.flags.optimize).encode(),
                                         path.encode("utf-8", "surrogateescape"), source])).hexdigest()
        cached = hub_envs_home() / "bytecode" / f"{key}.bin"
        try:
            return marshal.loads(cached.read_bytes())
        except (OSError, ValueError, EOFError, TypeError):
            pass
        code = self.source_to_code(source, path)
        if not sys.dont_write_bytecode:
            try:
                cached.parent.mkdir(parents=True, exist_ok=True)
                tmp = cached.with_name(f".{key}.{os.getpid()}.tmp")
                tmp.write_bytes(marshal.dumps(code))
                os.replace(tmp, cached)
            except OSError:
                pass
        return code

    def set_data(self, *args, **kwargs) -> None:  # no bytecode cache is written
        return None


_NO_CODE_DIRS = {*IGNORED_PARTS, DATASET_DIR, MEDIA_DIR}
_FINDER_DIRS: dict[str, list[str]] = {}  # package name -> the folders given a source-only finder


def _install_source_finders(name: str, folder: Path) -> None:
    """Make imports below ``folder`` use :class:`_SourceLoader` for ``.py`` files and nothing else."""
    dirs = [str(folder)]
    for dirpath, dirnames, _ in os.walk(folder):
        # no code lives in caches, hidden folders (a .venv!) or the generated dataset/ and media/
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d not in _NO_CODE_DIRS)
        dirs += [os.path.join(dirpath, d) for d in dirnames]
    for d in dirs:
        sys.path_importer_cache[d] = importlib.machinery.FileFinder(d, (_SourceLoader, [".py"]))
    _FINDER_DIRS[name] = dirs


def _root_package() -> types.ModuleType:
    root = sys.modules.get(ROOT_PACKAGE)
    if root is None:
        root = types.ModuleType(ROOT_PACKAGE, "Namespace for env code imported by hub-envs.")
        root.__path__ = []  # a package with no folder of its own
        sys.modules[ROOT_PACKAGE] = root
    return root


def import_env_folder(folder: str | Path, key: str) -> types.ModuleType:
    """Make ``folder`` importable as the package ``hub_envs_code.<key>`` and return that package.

    Idempotent: the same key returns the package already imported.
    """
    folder = Path(folder).resolve()
    if not folder.is_dir():
        raise InvalidRepoFormatError(f"Env code folder {folder} does not exist. Pass the folder that holds the env's .py files.")
    key = module_key(key)
    name = f"{ROOT_PACKAGE}.{key}"
    if name in sys.modules:
        return sys.modules[name]
    root = _root_package()
    spec = importlib.util.spec_from_loader(name, loader=None, is_package=True)
    pkg = importlib.util.module_from_spec(spec)
    pkg.__path__ = [str(folder)]
    pkg.__file__ = None
    _install_source_finders(name, folder)
    sys.modules[name] = pkg
    setattr(root, key, pkg)
    return pkg


def is_imported(key: str) -> bool:
    """True if :func:`import_env_folder` already made the package for ``key`` in this process."""
    return f"{ROOT_PACKAGE}.{module_key(key)}" in sys.modules


def forget_env_folder(key: str) -> None:
    """Remove a package imported by :func:`import_env_folder` and all its submodules from ``sys.modules``."""
    name = f"{ROOT_PACKAGE}.{module_key(key)}"
    for mod in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
        del sys.modules[mod]
    for d in _FINDER_DIRS.pop(name, []):
        sys.path_importer_cache.pop(d, None)
    root = sys.modules.get(ROOT_PACKAGE)
    if root is not None and hasattr(root, module_key(key)):
        delattr(root, module_key(key))


def parse_entry_point(entry_point: str, *, where: str = "the manifest") -> tuple[str, str]:
    """Split ``"module:Attr"`` into its parts, or raise a precise error."""
    m = _ENTRY_POINT_RE.match(entry_point or "")
    if not m:
        raise InvalidRepoFormatError(
            f"Entry point {entry_point!r} in {where} is not of the form 'module:Attribute' "
            f"(for example 'pendulum_env:PendulumEnv', with pendulum_env.py next to it)."
        )
    return m.group("module"), m.group("attr")


def resolve_entry_point(package: types.ModuleType, entry_point: str, *, where: str = "the manifest"):
    """Import ``module`` relative to ``package`` and return ``attr`` (``"module:Attr"``)."""
    module_name, attr = parse_entry_point(entry_point, where=where)
    full = f"{package.__name__}.{module_name}"
    try:
        module = importlib.import_module(full)
    except ModuleNotFoundError as e:
        if e.name == full or (e.name and full.startswith(e.name + ".")) or e.name == full.rsplit(".", 1)[0]:
            raise InvalidRepoFormatError(
                f"Entry point {entry_point!r} in {where}: there is no module {module_name}.py in the env's code. "
                f"Fix the entry point or add the file."
            ) from e
        raise EnvCodeError(
            f"Importing {module_name} for entry point {entry_point!r} failed: {e}. "
            f"If it is a third-party package, declare it in the requirements; between the env's own files "
            f"use relative imports (from .{e.name} import ...)."
        ) from e
    except ValueError as e:
        if "already registered as" in str(e):  # draccus' register_subclass: a choice name is taken
            raise RegistrationConflictError(
                f"Importing {module_name} for entry point {entry_point!r} in {where} registers a draccus choice that is "
                f"already taken: {e}. Remove its @EnvConfig.register_subclass decorator: hub-envs registers the config "
                f"itself, under a name unique to the repo and commit."
            ) from e
        raise EnvCodeError(f"Importing {module_name} for entry point {entry_point!r} raised {type(e).__name__}: {e}") from e
    except Exception as e:  # the env's own code raised at import time
        raise EnvCodeError(f"Importing {module_name} for entry point {entry_point!r} raised {type(e).__name__}: {e}") from e
    obj = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise InvalidRepoFormatError(
                f"Entry point {entry_point!r} in {where}: {module_name}.py has no attribute {attr!r}. "
                f"Fix the entry point or define it."
            ) from None
    return obj
