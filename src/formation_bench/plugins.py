"""Optimisers and scenarios from outside the repository: entry points and plugin modules.

Two ways in, both loaded before a name is looked up:

- an installed package declares an entry point in the group
  ``formation_bench.optimizers`` (or ``formation_bench.scenarios``) whose value is a
  module; importing that module registers its optimisers (or scenarios);
- ``--plugin MODULE_OR_FILE`` on the command line (or :func:`load_plugin`) imports a
  module by name or a ``.py`` file by path.

Sweeps send the plugins given with ``--plugin`` to their workers
(:func:`loaded_plugins`), so a plugin optimiser runs in every worker process,
local or on a Dask cluster (a file path must then exist on the workers too).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from collections.abc import Callable, Iterator, MutableMapping
from importlib import metadata
from pathlib import Path
from types import ModuleType
from typing import Generic, TypeVar

OPTIMIZER_GROUP = "formation_bench.optimizers"
"""Entry-point group of optimiser plugins."""
SCENARIO_GROUP = "formation_bench.scenarios"
"""Entry-point group of scenario plugins."""


class PluginError(RuntimeError):
    """A plugin that cannot be loaded; the message names it and why."""


class DuplicateNameError(ValueError):
    """A name registered twice; the message names who registered it first."""


_loaded_groups: set[str] = set()
_loading_groups: set[str] = set()
_plugins: dict[str, ModuleType] = {}
_loading: list[str] = []
"""What is being imported now (innermost last), so that a registry can say who registered a
name: an entry point or a ``--plugin``."""


def registering_source() -> str:
    """Who is registering names at this moment, for messages about duplicates."""
    return _loading[-1] if _loading else "formation-bench itself"


def load_entry_points(group: str) -> None:
    """Import every module registered in the entry-point ``group`` (once per process)."""
    if group in _loaded_groups or group in _loading_groups:
        return
    _loading_groups.add(group)
    try:
        for entry in metadata.entry_points(group=group):
            source = (
                f"entry point {entry.name!r} = {entry.value!r} of group {group!r} "
                f"(from {entry.dist.name if entry.dist else 'an unknown package'})"
            )
            _loading.append(source)
            try:
                entry.load()
            except Exception as err:
                raise PluginError(f"{source} failed to load: {_reason(err)}") from err
            finally:
                _loading.pop()
        _loaded_groups.add(group)
    finally:
        _loading_groups.discard(group)


def load_plugin(source: str) -> ModuleType:
    """Import a plugin module by dotted name, or a ``.py`` file by path (each once).

    Raises :class:`PluginError` naming the plugin when it cannot be found or fails.
    """
    if source in _plugins:
        return _plugins[source]
    path = Path(source)
    _loading.append(f"--plugin {source}")
    try:
        if source.endswith(".py") or path.is_file():
            module = _load_file(source, path)
        else:
            module = _import_module(source)
    finally:
        _loading.pop()
    _plugins[source] = module
    return module


def _import_module(source: str) -> ModuleType:
    try:
        return importlib.import_module(source)
    except ModuleNotFoundError as err:
        if err.name is not None and source.startswith(err.name):
            raise PluginError(
                f"--plugin {source}: no module named {err.name!r} (give an importable module "
                "name or the path of a .py file)"
            ) from None
        raise PluginError(f"--plugin {source}: {_reason(err)}") from err
    except Exception as err:
        raise PluginError(f"--plugin {source}: {_reason(err)}") from err


def _reason(err: Exception) -> str:
    """Why a plugin failed, in one line: a refused name as it is, anything else with its type."""
    if isinstance(err, DuplicateNameError):
        return str(err)
    return f"{type(err).__name__}: {err}"


def _load_file(source: str, path: Path) -> ModuleType:
    if not path.is_file():
        raise PluginError(f"--plugin {source}: no such file")
    resolved = path.resolve()
    # a stable module name per file, so that the same file loaded twice is one module
    digest = hashlib.sha256(str(resolved).encode()).hexdigest()[:12]
    name = f"formation_bench_plugin_{resolved.stem}_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, resolved)
    if spec is None or spec.loader is None:
        raise PluginError(f"--plugin {source}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as err:
        del sys.modules[name]
        raise PluginError(f"--plugin {source}: {_reason(err)}") from err
    return module


def loaded_plugins() -> tuple[str, ...]:
    """The plugins loaded by :func:`load_plugin`, files as absolute paths, in load order."""
    return tuple(
        str(Path(s).resolve()) if (s.endswith(".py") or Path(s).is_file()) else s for s in _plugins
    )


def load_plugins(sources: tuple[str, ...] | list[str]) -> None:
    """The installed entry points, then :func:`load_plugin` for each source (how commands
    and their workers load what they may look up).

    Entry points first and always, so that a name registered both by an installed package
    and by a ``--plugin`` is refused by every command, not only by those that list names.
    """
    load_entry_points(OPTIMIZER_GROUP)
    load_entry_points(SCENARIO_GROUP)
    for source in sources:
        load_plugin(source)


T = TypeVar("T")


class Registry(MutableMapping[str, T], Generic[T]):
    """Names to entries, refusing duplicates; loads its entry-point group on first use.

    A plain mapping otherwise (tests may ``monkeypatch.setitem`` into it).
    """

    def __init__(self, kind: str, group: str, check: Callable[[str, T], None] | None = None):
        self.kind = kind
        """What the entries are, for messages (``optimizer``, ``scenario``)."""
        self.group = group
        """The entry-point group loaded before the first lookup."""
        self._check = check
        self._entries: dict[str, T] = {}
        self._sources: dict[str, str] = {}
        self._missing: dict[str, str] = {}

    def _load(self) -> None:
        load_entry_points(self.group)

    def add(self, name: str, entry: T) -> T:
        """Register ``entry`` under ``name``; refuses a name already taken."""
        if (
            not isinstance(name, str)
            or not name
            or not name.replace("-", "").replace("_", "").isalnum()
        ):
            raise ValueError(f"{self.kind} name must be alphanumeric with '-' or '_', got {name!r}")
        if name in self._entries:
            raise DuplicateNameError(
                f"{self.kind} name {name!r} is already registered by "
                f"{self._sources.get(name, 'formation-bench itself')}; give one of them "
                "another name"
            )
        if self._check is not None:
            self._check(name, entry)
        self._entries[name] = entry
        self._sources[name] = registering_source()
        return entry

    def add_missing(self, name: str, reason: str) -> None:
        """Note that ``name`` is left unregistered here, and why (e.g. an extra to install)."""
        self._missing[name] = reason

    def missing(self) -> dict[str, str]:
        """Names left unregistered in this installation, and why."""
        self._load()
        return dict(self._missing)

    def unknown(self, name: str) -> KeyError:
        """The error for a name that is not registered, listing the allowed names."""
        self._load()
        if name in self._missing:
            return KeyError(f"{self.kind} {name!r} is not available: {self._missing[name]}")
        return KeyError(f"unknown {self.kind} {name!r}; registered: {', '.join(sorted(self))}")

    def __getitem__(self, name: str) -> T:
        if name not in self._entries:
            self._load()
        return self._entries[name]

    def __setitem__(self, name: str, entry: T) -> None:
        self._entries[name] = entry

    def __delitem__(self, name: str) -> None:
        del self._entries[name]
        self._sources.pop(name, None)

    def __contains__(self, name: object) -> bool:
        if name not in self._entries:
            self._load()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        self._load()
        return iter(list(self._entries))

    def __len__(self) -> int:
        self._load()
        return len(self._entries)
