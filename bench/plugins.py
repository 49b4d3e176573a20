"""Users' own plants (and designs) from a Python file that registers them when imported::

    python -m bench run --plugin my_plants.py --plant my_plant

:func:`load_plugin` imports the file under a private module name and builds every plant it registered
with its defaults; any failure raises :class:`PluginError` naming the file (and the line) and leaves
the registries as they were.
"""

from __future__ import annotations

import contextlib
import importlib.util
import re
import sys
import traceback
from pathlib import Path

from bench.errors import PluginError
from bench.registry import DESIGNS, PLANTS

__all__ = ["load_plugin", "load_plugins", "loaded_plugins"]

#: The plugin files this process loaded, in order, each with the ids it registered (:func:`loaded_plugins`).
_LOADED: dict[Path, list[str]] = {}


def _module_name(path: Path) -> str:
    stem = re.sub(r"\W", "_", path.stem) or "plugin"
    base = f"oslbench_plugin_{stem}"
    name, k = base, 1
    while name in sys.modules:
        k += 1
        name = f"{base}_{k}"
    return name


def _where(exc: BaseException, path: Path) -> str:
    """' (line N)' for the deepest traceback frame inside the plugin file, if any."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f" (line {exc.lineno})"
    line = None
    for frame in traceback.extract_tb(exc.__traceback__):
        try:
            if Path(frame.filename).resolve() == path:
                line = frame.lineno
        except (OSError, ValueError):
            continue
    return f" (line {line})" if line else ""


def load_plugin(path) -> list[str]:
    """Import a plugin file and validate what it registered.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    list of str
        The plant and design ids the file registered, plants first.

    Raises
    ------
    PluginError
        A missing file, an import failure (syntax error, exception, duplicate id), nothing registered,
        or a plant that cannot be built with its defaults or has another id; the message starts
        with ``plugin <path>:``.
    """
    from plants import Plant

    shown = str(path)
    p = Path(path)
    if not p.exists():
        raise PluginError(f"plugin {shown}: no such file")
    if not p.is_file():
        raise PluginError(f"plugin {shown}: not a file")
    p = p.resolve()
    # built-in plants and designs first, so that a clash is reported against them
    before = set(PLANTS.ids()), set(DESIGNS.ids())
    name = _module_name(p)

    def new_ids() -> tuple[list[str], list[str]]:
        return [i for i in PLANTS.ids() if i not in before[0]], [i for i in DESIGNS.ids() if i not in before[1]]

    try:
        _execute(p, name)
        plants, designs = new_ids()
        if not plants and not designs:
            raise PluginError("registers no plant or design (decorate a keyword-only factory with "
                              "@register_plant(\"my_plant\") from bench.registry)")
        for pid in plants:  # it builds, is a Plant and has the id it was registered under
            plant = _build("plant", PLANTS, pid, p)
            if not isinstance(plant, Plant):
                raise PluginError(f"the factory of plant {pid!r} returned a {type(plant).__name__}, not a plants.Plant")
            if plant.id != pid:
                raise PluginError(f"plant registered as {pid!r} has id {plant.id!r}; "
                                  "use the same id in @register_plant and Plant(id=...)")
        for did in designs:
            _build("design", DESIGNS, did, p)
    except PluginError as exc:  # undo: unregister what the file registered and forget its module
        for registry, ids in zip((PLANTS, DESIGNS), new_ids()):
            for i in ids:
                registry.unregister(i)
        sys.modules.pop(name, None)
        raise PluginError(f"plugin {shown}: {exc}") from None
    _LOADED[p] = plants + designs
    return plants + designs


def loaded_plugins() -> list[Path]:
    """The plugin files this process loaded (resolved paths, in load order) whose ids are still registered.

    A worker started by spawn or forkserver loads them again (:mod:`bench.executors`): unlike a forked one, it
    does not inherit the registries.
    """
    ids = set(PLANTS.ids()) | set(DESIGNS.ids())
    return [p for p, registered in _LOADED.items() if any(i in ids for i in registered)]


def _execute(p: Path, name: str) -> None:
    """Execute the file as the module ``name``, helper modules beside it importable; PluginError on a failure."""
    spec = importlib.util.spec_from_file_location(name, p)
    if spec is None or spec.loader is None:
        raise PluginError("cannot be imported as a Python module (is it a .py file?)")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.path.insert(0, str(p.parent))
    try:
        spec.loader.exec_module(module)
    except SyntaxError as exc:
        raise PluginError(f"syntax error{_where(exc, p)}: {exc.msg}") from None
    except Exception as exc:  # ImportError, RegistryError (duplicate id), anything the file raises
        raise PluginError(f"failed to import{_where(exc, p)}: {type(exc).__name__}: {exc}") from None
    except SystemExit as exc:  # a plugin calling sys.exit() must not end the run silently
        raise PluginError(f"called sys.exit({exc.code!r}) while being imported") from None
    finally:
        with contextlib.suppress(ValueError):
            sys.path.remove(str(p.parent))


def _build(kind: str, registry, rid: str, p: Path):
    """``registry.create(rid)`` with the factory's defaults; PluginError naming the failure."""
    try:
        return registry.create(rid)
    except Exception as exc:
        raise PluginError(f"{kind} {rid!r} cannot be built with its defaults{_where(exc, p)}: "
                          f"{type(exc).__name__}: {exc}") from None


def load_plugins(paths) -> list[str]:
    """Load several plugin files in order (:func:`load_plugin`); stops at the first failure. Returns every id."""
    ids: list[str] = []
    for path in paths or ():
        ids.extend(load_plugin(path))
    return ids
