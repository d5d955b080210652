"""Import an env's code from a folder as a package named after its repo and revision: relative imports work, two
revisions live side by side, nothing goes on ``sys.path``, and only the ``.py`` sources ever run.

Example:
    >>> from hub_envs.envcode.importing import import_env_folder, resolve_entry_point
    >>> pkg = import_env_folder("envs/pendulum", key="local-pendulum")      # doctest: +SKIP
    >>> EnvCls = resolve_entry_point(pkg, "pendulum_env:PendulumEnv")       # doctest: +SKIP
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import re
import sys
import types
from pathlib import Path

from hub_envs.errors import EnvCodeError, InvalidRepoFormatError, RegistrationConflictError
from hub_envs.repo.format import ENTRY_POINT_RE, safe_text

ROOT_PACKAGE = "hub_envs_code"


def module_key(*parts: str) -> str:
    """A valid Python identifier built from ``parts`` (e.g. repo id and sha)."""
    raw = "__".join(parts)
    key = re.sub(r"\W", "_", raw)
    return key if not key[0].isdigit() else f"_{key}"


class _SourceLoader(importlib.machinery.SourceFileLoader):
    """Loads a module from its ``.py`` source only: never reads or writes any bytecode.

    There is no bytecode cache at all, not ``__pycache__`` and not one of hub-envs' own: a cache entry
    is code that runs on a later load, and anyone able to write the cache folder could plant one. What
    it saved is small (compiling an env's sources happens once per process).
    """

    def get_code(self, fullname):
        path = self.get_filename(fullname)
        return self.source_to_code(self.get_data(path), path)

    def set_data(self, *args, **kwargs) -> None:  # no bytecode cache is written
        return None


_FINDER_DIRS: dict[str, set[str]] = {}  # package name -> the folders given a source-only finder


class _SourceOnlyFinder(importlib.machinery.FileFinder):
    """A ``FileFinder`` that finds ``.py`` sources only (no ``.pyc``, no extension modules), and gives
    every package folder it finds (regular or namespace: ``dataset/``, ``media/``, dot-folders alike) a
    finder of its own kind before anything is imported from it, so no folder of an env's code is ever
    searched by Python's default finders (which honour ``__pycache__`` and ``.so`` files)."""

    def __init__(self, path: str, package: str):
        super().__init__(path, (_SourceLoader, [".py"]))
        self._package = package

    def find_spec(self, fullname, target=None):
        spec = super().find_spec(fullname, target)
        if spec is not None and spec.submodule_search_locations:
            for d in list(spec.submodule_search_locations):
                _install_finder(self._package, str(d))
        return spec


def _install_finder(name: str, folder: str) -> None:
    if not isinstance(sys.path_importer_cache.get(folder), _SourceOnlyFinder):
        sys.path_importer_cache[folder] = _SourceOnlyFinder(folder, name)
    _FINDER_DIRS.setdefault(name, set()).add(folder)


def _install_source_finders(name: str, folder: Path) -> None:
    """Make imports below ``folder`` use :class:`_SourceLoader` for ``.py`` files and nothing else.

    ``folder`` gets a :class:`_SourceOnlyFinder`, which hands one to every package folder it finds
    below (``dataset/``, ``media/`` and hidden folders alike) before anything is imported from it. No
    folder is skipped, and none is walked in advance (a local folder may hold a large ``.venv``).
    """
    _install_finder(name, str(folder))


def _root_package() -> types.ModuleType:
    root = sys.modules.get(ROOT_PACKAGE)
    if root is None:
        root = types.ModuleType(ROOT_PACKAGE, "Namespace for env code imported by hub-envs.")
        root.__path__ = []  # a package with no folder of its own
        sys.modules[ROOT_PACKAGE] = root
    return root


def import_env_folder(folder: str | Path, key: str) -> types.ModuleType:
    """Make ``folder`` importable as the package ``hub_envs_code.<key>``. Idempotent: the same key returns the package
    already imported.

    Args:
        folder: the env's code folder.
        key: names the package (:func:`module_key` of repo and revision).

    Returns:
        The package (its modules import from the ``.py`` sources only).

    Raises:
        InvalidRepoFormatError: the folder does not exist.
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
    """Whether :func:`import_env_folder` already made the package for ``key`` in this process.

    Args:
        key: the package's key.

    Returns:
        True when it is in ``sys.modules``.
    """
    return f"{ROOT_PACKAGE}.{module_key(key)}" in sys.modules


def forget_env_folder(key: str) -> None:
    """Remove a package imported by :func:`import_env_folder`, and all its submodules, from ``sys.modules``.

    Args:
        key: the package's key.
    """
    name = f"{ROOT_PACKAGE}.{module_key(key)}"
    for mod in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
        del sys.modules[mod]
    still_used = set().union(*(dirs for other, dirs in _FINDER_DIRS.items() if other != name))
    for d in _FINDER_DIRS.pop(name, ()):
        # a folder another live package (the same local folder under another digest) still imports from keeps its finder
        if d not in still_used and isinstance(sys.path_importer_cache.get(d), _SourceOnlyFinder):
            sys.path_importer_cache.pop(d, None)
    root = sys.modules.get(ROOT_PACKAGE)
    if root is not None and hasattr(root, module_key(key)):
        delattr(root, module_key(key))


def parse_entry_point(entry_point: str, *, where: str = "the manifest") -> tuple[str, str]:
    """Split ``"module:Attr"`` into its parts.

    Args:
        entry_point: the entry point.
        where: names its source in messages.

    Returns:
        ``(module, attr)``.

    Raises:
        InvalidRepoFormatError: not of the form ``module:Attribute``.
    """
    m = ENTRY_POINT_RE.match(entry_point or "")
    if not m:
        raise InvalidRepoFormatError(
            f"Entry point {entry_point!r} in {where} is not of the form 'module:Attribute' "
            f"(for example 'pendulum_env:PendulumEnv', with pendulum_env.py next to it)."
        )
    return m.group("module"), m.group("attr")


def resolve_entry_point(package: types.ModuleType, entry_point: str, *, where: str = "the manifest"):
    """Import ``module`` relative to ``package`` and return its ``attr``.

    Args:
        package: the env's package (:func:`import_env_folder`).
        entry_point: ``"module:Attr"``.
        where: names its source in messages.

    Returns:
        The attribute (a class, a function...).

    Raises:
        InvalidRepoFormatError: no such module or attribute.
        EnvCodeError: importing the module raised.
    """
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
            f"Importing {module_name} for entry point {entry_point!r} failed: {safe_text(e)}. "
            f"If it is a third-party package, declare it in the requirements; between the env's own files "
            f"use relative imports (from .{safe_text(e.name)} import ...)."
        ) from e
    except ValueError as e:
        if "already registered as" in str(e):  # draccus' register_subclass: a choice name is taken
            raise RegistrationConflictError(
                f"Importing {module_name} for entry point {entry_point!r} in {where} registers a draccus choice that is "
                f"already taken: {safe_text(e)}. Remove its @EnvConfig.register_subclass decorator: hub-envs registers the config "
                f"itself, under a name unique to the repo and commit."
            ) from e
        raise EnvCodeError(
            f"Importing {module_name} for entry point {entry_point!r} raised {type(e).__name__}: {safe_text(e)}"
        ) from e
    except Exception as e:  # the env's own code raised at import time
        raise EnvCodeError(
            f"Importing {module_name} for entry point {entry_point!r} raised {type(e).__name__}: {safe_text(e)}"
        ) from e
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
