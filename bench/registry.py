"""Registries of plants and designs: a decorator registers a factory under an id.

The modules of the ``plants`` and ``designs`` packages (not those starting with ``_``) are imported on
first use, so adding a plant or a design is adding one file. Ids name files and are matched by globs,
so :func:`check_id` allows only :data:`ID_CHARS`, at most :data:`ID_MAX_CHARS` of them; unknown ids raise :class:`UnknownIdError` with a
"did you mean".
"""

from __future__ import annotations

import difflib
import fnmatch
import functools
import importlib
import pkgutil
import re
from dataclasses import dataclass
from typing import Any, Callable

from bench.errors import RegistryError, UnknownIdError

__all__ = ["DESIGNS", "PLANTS", "Registry", "register_design", "register_plant"]


@dataclass(frozen=True)
class Entry:
    """A registered factory with its id, one-line summary and defining module; ``default`` False: run only when
    a glob names it (not in the default selection, :meth:`Registry.select`)."""

    id: str
    factory: Callable[..., Any]
    summary: str
    module: str
    order: int = 100
    default: bool = True


#: The characters an id may hold (ids name files: no path separator, blank, glob or shell character).
ID_CHARS = "letters A-Z a-z, digits 0-9, '_', '-', '.', '+'"
_ID_RE = re.compile(r"[A-Za-z0-9_.+-]+")
#: The longest id: the longest file name a report writes, ``<plant>__<design>.png``, stays within the usual
#: 255-byte limit of a file name.
ID_MAX_CHARS = 100


def check_id(id: Any, kind: str = "id") -> str:
    """``id`` if it is a non-empty string of at most :data:`ID_MAX_CHARS` characters of :data:`ID_CHARS` not
    starting with '.' or '-', else a :class:`RegistryError` naming the id, the offending character (or the length)
    and the allowed ones (``kind`` starts the message).
    """
    if not isinstance(id, str) or not id:
        raise RegistryError(f"{kind} id {id!r}: must be a non-empty string of {ID_CHARS}")
    if len(id) > ID_MAX_CHARS:
        raise RegistryError(f"{kind} id {id[:40]!r}... ({len(id)} characters): at most {ID_MAX_CHARS} characters "
                            "(ids name the report's files, and a file name has at most 255 bytes)")
    if not _ID_RE.fullmatch(id):
        bad = next(c for c in id if not _ID_RE.fullmatch(c))
        raise RegistryError(f"{kind} id {id!r}: the character {bad!r} is not allowed (ids name files); "
                            f"use only {ID_CHARS}")
    if id[0] in ".-":
        raise RegistryError(f"{kind} id {id!r}: must not start with {id[0]!r} (a hidden file, or an option); "
                            f"use only {ID_CHARS}, starting with a letter, a digit or '_'")
    return id


class Registry:
    """An ordered mapping from id to :class:`Entry`, filled by ``package``'s modules."""

    def __init__(self, kind: str, package: str):
        self.kind = kind
        self.package = package
        self._entries: dict[str, Entry] = {}
        self._discovered = False

    def register(self, id: str, factory: Callable[..., Any], summary: str | None = None, *, order: int = 100,
                 default: bool = True) -> None:
        """Register ``factory`` under ``id`` (sorted by ``order``, then id; ``default`` False: only on request, see
        :meth:`select`); RegistryError on a bad id."""
        check_id(id, self.kind)
        if id in self._entries:
            other = self._entries[id].module
            raise RegistryError(f"duplicate {self.kind} id {id!r} (already registered by {other})")
        module = getattr(factory, "__module__", "?")
        first_line = (getattr(factory, "__doc__", None) or "").strip().partition("\n")[0].strip()
        self._entries[id] = Entry(id, factory, summary or first_line, module, order, bool(default))

    def unregister(self, id: str) -> None:
        """Remove an id (used by plugin loading on failure and by tests)."""
        self._entries.pop(id, None)

    def discover(self) -> "Registry":
        """Import every public module of the package once, so their decorators run."""
        if not self._discovered:
            self._discovered = True
            pkg = importlib.import_module(self.package)
            for info in pkgutil.iter_modules(pkg.__path__):
                if not info.name.startswith("_"):
                    importlib.import_module(f"{self.package}.{info.name}")
        return self

    def ids(self) -> list[str]:
        """All registered ids, sorted by (order, id)."""
        self.discover()
        return [e.id for e in sorted(self._entries.values(), key=lambda e: (e.order, e.id))]

    def defaults(self) -> list[str]:
        """The default selection: the registered ids without ``default=False``, sorted as :meth:`ids`."""
        return [i for i in self.ids() if self._entries[i].default]

    def __contains__(self, id: str) -> bool:
        self.discover()
        return id in self._entries

    def __getitem__(self, id: str) -> Entry:
        self.discover()
        try:
            return self._entries[id]
        except KeyError:
            raise UnknownIdError(self.kind, id, self.suggest(id)) from None

    def suggest(self, pattern: str) -> list[str]:
        """Close matches for a mistyped id."""
        return difflib.get_close_matches(pattern, self.ids(), n=2, cutoff=0.5)

    def select(self, patterns: list[str] | None, *, keep_order: bool = False) -> list[str]:
        """Ids matching any of the glob ``patterns`` (the default selection, :meth:`defaults`, if None or empty:
        an id registered with ``default=False`` runs only when a pattern matches it).

        Parameters
        ----------
        patterns : list of str, optional
        keep_order : bool
            False: the registry's order; True: the order of the patterns, each id once.

        Raises
        ------
        UnknownIdError
            If one pattern matches nothing.
        """
        ids = self.ids()
        if not patterns:
            return self.defaults()
        chosen: list[str] = []
        for pat in patterns:
            hits = [i for i in ids if fnmatch.fnmatchcase(i, pat)]
            if not hits:
                raise UnknownIdError(self.kind, pat, self.suggest(pat))
            chosen.extend(h for h in hits if h not in chosen)
        return chosen if keep_order else [i for i in ids if i in chosen]

    def create(self, id: str, **overrides: Any) -> Any:
        """Build the registered object ``id``."""
        return self[id].factory(**overrides)


PLANTS = Registry("plant", "plants")
DESIGNS = Registry("design", "designs")


def register_plant(id: str, summary: str | None = None, *, order: int = 100, default: bool = True):
    """Decorator registering a keyword-only plant factory under ``id`` (``default`` False: not in the default
    selection, run when a ``--plant`` glob names it, e.g. a plant whose simulation is long)."""

    def deco(factory):
        PLANTS.register(id, factory, summary, order=order, default=default)
        return factory

    return deco


def register_design(id: str, summary: str | None = None, *, order: int = 100, **fixed: Any):
    """Decorator registering a design class (or factory) under ``id``, with ``fixed`` keyword defaults bound."""

    def deco(cls):
        factory = cls
        if fixed:
            factory = functools.partial(cls, **fixed)
            factory.__doc__ = cls.__doc__
            factory.__module__ = cls.__module__
        DESIGNS.register(id, factory, summary, order=order)
        return cls

    return deco
