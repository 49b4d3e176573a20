"""Registries of plants and designs: a decorator registers a factory under an id.

The modules of the ``plants`` and ``designs`` packages (not those starting with ``_``) are imported on
first use, so adding a plant or a design is adding one file. Ids name files and are matched by globs,
so :func:`check_id` allows only :data:`ID_CHARS`, at most :data:`ID_MAX_CHARS` of them; unknown ids raise :class:`UnknownIdError` with a
"did you mean".

Objects given to :func:`bench.run` are not registered: :func:`object_id` names them (a design by its class's
registered id and the hyperparameters that differ from the defaults, ``thm1[phi1=0.05]``; a plant by its ``id``)
and :meth:`Registry.overlay` makes them visible for the one call only.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import fnmatch
import functools
import hashlib
import importlib
import numbers
import pkgutil
import re
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping

from bench.errors import RegistryError, UnknownIdError

__all__ = ["DESIGNS", "PLANTS", "Registry", "object_id", "register_design", "register_plant"]


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
        self._overlays: list[dict[str, Entry]] = []
        self._discovered = False

    def _visible(self) -> dict[str, Entry]:
        """The registered entries and those of the overlays in force."""
        if not self._overlays:
            return self._entries
        out = dict(self._entries)
        for layer in self._overlays:
            out.update(layer)
        return out

    def register(self, id: str, factory: Callable[..., Any], summary: str | None = None, *, order: int = 100,
                 default: bool = True) -> None:
        """Register ``factory`` under ``id`` (sorted by ``order``, then id; ``default`` False: only on request, see
        :meth:`select`); RegistryError on a bad id."""
        check_id(id, self.kind)
        if id in self._visible():
            other = self._visible()[id].module
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
        return [e.id for e in sorted(self._visible().values(), key=lambda e: (e.order, e.id))]

    def registered(self, id: str) -> bool:
        """Whether ``id`` is registered (an overlay's entry is not)."""
        self.discover()
        return id in self._entries

    def defaults(self) -> list[str]:
        """The default selection: the registered ids without ``default=False``, sorted as :meth:`ids`."""
        return [i for i in self.ids() if self._visible()[i].default]

    def __contains__(self, id: str) -> bool:
        self.discover()
        return id in self._visible()

    def __getitem__(self, id: str) -> Entry:
        self.discover()
        try:
            return self._visible()[id]
        except KeyError:
            raise UnknownIdError(self.kind, id, self.suggest(id)) from None

    @contextlib.contextmanager
    def overlay(self, objects: Mapping[str, Any], summary: str = "object") -> Iterator[None]:
        """Within the block, each object of ``objects`` (id -> object) is an entry of this registry whose factory
        returns it (``factory._bench_object`` is the object, so that :mod:`bench.executors` sends it to fresh
        workers); afterwards the registry is as before. Nothing is registered: the same ids may come again.

        Parameters
        ----------
        objects : mapping
            Id (:func:`check_object_id`) -> the object.
        summary : str
            The entries' summary.

        Raises
        ------
        RegistryError
            An id that is bad, registered, or in an overlay already in force.
        """
        self.discover()
        layer = {}
        for i, obj in objects.items():
            check_object_id(i, self.kind)
            if i in self._visible():
                raise RegistryError(f"{self.kind} id {i!r} is already registered (by {self._visible()[i].module})")
            layer[i] = Entry(i, _returning(obj), summary, __name__, 200)
        self._overlays.append(layer)
        try:
            yield
        finally:
            self._overlays[:] = [x for x in self._overlays if x is not layer]

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


def _returning(obj: Any) -> Callable[..., Any]:
    """A factory returning ``obj`` (its ``_bench_object``)."""

    def factory(**overrides: Any) -> Any:
        return obj

    factory._bench_object = obj
    return factory


# -- ids of objects given to bench.run -----------------------------------------------------------------
#: The characters an object's id may hold beyond :data:`ID_CHARS`: its hyperparameters, ``thm1[phi1=0.05]``.
OBJECT_ID_EXTRA = "[]=,()~"
_OBJECT_ID_RE = re.compile(r"[A-Za-z0-9_.+\-\[\]=,()~]+")
#: A hyperparameter's value longer than this is named by a digest (``~1a2b3c4d``).
VALUE_CHARS = 32


def check_object_id(id: Any, kind: str = "id") -> str:
    """:func:`check_id` for the id of an object given to :func:`bench.run`: its characters may also be
    :data:`OBJECT_ID_EXTRA` (they name files on every system, but are no glob: such ids are selected by object)."""
    if isinstance(id, str) and id and _OBJECT_ID_RE.fullmatch(id) and id[0] not in ".-[" \
            and len(id) <= ID_MAX_CHARS:
        return id
    return check_id(id, kind)


def _digest(text: str, n: int = 8) -> str:
    return hashlib.sha256(text.encode("utf-8", "replace")).hexdigest()[:n]


def _value_text(v: Any) -> str:
    """A hyperparameter's value in an id: repr-like and short (None, True, 3, 0.05, name, (1,2)); a long or
    unprintable value by a digest of it, ``~1a2b3c4d``."""
    import numpy as np

    if v is None or isinstance(v, (bool, np.bool_)):
        return str(None if v is None else bool(v))
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        return repr(float(v))
    text = None
    if isinstance(v, str):
        text = v if re.fullmatch(r"[A-Za-z0-9_.+-]+", v) else None
        raw = repr(v)
    elif isinstance(v, (tuple, list)):
        text = "(" + ",".join(_value_text(x) for x in v) + ")"
        raw = text
    elif isinstance(v, Mapping) and all(isinstance(k, str) and re.fullmatch(r"[A-Za-z0-9_]+", k) for k in v):
        text = "(" + ",".join(f"{k}={_value_text(v[k])}" for k in sorted(v)) + ")"
        raw = text
    elif isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        raw = f"{a.dtype.str}{a.shape}" + (a.tobytes().hex() if not a.dtype.hasobject else repr(a.tolist()))
    elif callable(v):
        raw = f"{getattr(v, '__module__', '')}.{getattr(v, '__qualname__', type(v).__qualname__)}"
    else:
        raw = re.sub(r" at 0x[0-9a-fA-F]+", "", repr(v))  # no memory address: the same value, the same id
    if text is None or len(text) > VALUE_CHARS:
        return "~" + _digest(raw)
    return text


def _same(a: Any, b: Any) -> bool:
    """Whether two hyperparameter values are the same: equal, or (arrays) written alike."""
    try:
        eq = a == b
        if isinstance(eq, bool):
            return eq
    except Exception:  # noqa: BLE001 - an object that cannot be compared: by its text
        pass
    return type(a) is type(b) and _value_text(a) == _value_text(b)


def _defaults(cls: type) -> dict[str, Any]:
    """The defaults of a dataclass's init fields (a field without a default is absent)."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.init and f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.init and f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def _values(obj: Any) -> dict[str, Any]:
    """A dataclass object's init fields by name."""
    return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}


def _changed(obj: Any, defaults: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """``{name: value text}`` of ``obj``'s init fields that differ from ``defaults`` (a field without a default
    always); a dataclass value by its own changed fields (``name.field``), after its class's name when the default
    is of another class."""
    out: dict[str, str] = {}
    for name, v in _values(obj).items():
        if name in defaults and _same(v, defaults[name]):
            continue
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            default = defaults.get(name)
            if type(default) is type(v):
                inner = _values(default)
            else:
                out[prefix + name] = _class_id(type(v))
                inner = _defaults(type(v))
            out.update(_changed(v, inner, f"{prefix}{name}."))
        else:
            out[prefix + name] = _value_text(v)
    return out


def _with_params(base: str, changed: Mapping[str, str]) -> str:
    """``base[name=value,...]`` (names sorted); a digest of them when the id would be too long."""
    if not changed:
        return base
    inner = ",".join(f"{k}={changed[k]}" for k in sorted(changed))
    out = f"{base}[{inner}]"
    return out if len(out) <= ID_MAX_CHARS else f"{base}[~{_digest(inner, 12)}]"


def _class_id(cls: type) -> str:
    """A class's name in lower case, as an id (characters outside :data:`ID_CHARS` as ``_``)."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", cls.__name__.lower()).lstrip(".-") or "design"


def _registered_as(registry: "Registry", obj: Any) -> list[tuple[str, dict]]:
    """The ids under which ``registry`` builds objects of ``obj``'s class, each with the hyperparameters its entry
    builds by default (registry order): the class itself, the class with fixed keywords (``functools.partial``), or
    a factory function declared to return the class (called without arguments: a pairing of parts)."""
    cls = type(obj)
    out = []
    for i in registry.ids():
        if not registry.registered(i):
            continue
        f = registry[i].factory
        if f is cls:
            out.append((i, _defaults(cls)))
        elif isinstance(f, functools.partial) and f.func is cls and not f.args:
            out.append((i, {**_defaults(cls), **f.keywords}))
        elif not isinstance(f, type) and getattr(f, "__annotations__", {}).get("return") in (cls, cls.__name__):
            try:
                default = f()
            except Exception:  # noqa: BLE001 - a factory that needs arguments: not this object's default
                continue
            if type(default) is cls:
                out.append((i, _values(default)))
    return out


def _design_id(obj: Any) -> tuple[str, bool]:
    """(id, whether the registry's entry of that id builds an equal design) of a Design object."""
    candidates = [(i, _changed(obj, defaults)) for i, defaults in _registered_as(DESIGNS, obj)]
    if candidates:
        i, changed = min(candidates, key=lambda c: len(c[1]))  # min keeps the first of equals: registry order
        return _with_params(i, changed), not changed
    return _with_params(_class_id(type(obj)), _changed(obj, _defaults(type(obj)))), False


def _same_plant(a: Any, b: Any) -> bool:
    """Whether two plants are the same: equal fields (callables by name) and what their callables compute at the
    cache's probe states (:meth:`bench.cache.Cache.plant_fingerprint`)."""
    from bench.cache import Cache

    fp = Cache(".").plant_fingerprint
    try:
        one, two = fp(a, a.id), fp(b, b.id)
    except Exception:  # noqa: BLE001 - a plant whose callables fail cannot be told the same
        return False
    one.pop("modules"), two.pop("modules")
    return one == two


def object_id(obj: Any, kind: str) -> tuple[str, bool]:
    """The id of a Plant or Design object given to :func:`bench.run`, and whether it is the registered entry of
    that id (then the registry's own entry runs it; else an overlay does, for that call).

    A design is named by the id its class is registered under (the registration whose fixed keywords leave the
    fewest differences; an unregistered class: its name in lower case; a pairing of parts:
    the registered pairing of its parts) and the hyperparameters that differ from those defaults, sorted by name,
    with repr-like short values: ``thm1[phi1=0.05]``, ``lqr+lqe[feedback.Q=~1a2b3c4d]``. A plant keeps its ``id``.

    Parameters
    ----------
    obj : plants.Plant or designs.Design
    kind : {"plant", "design"}

    Returns
    -------
    (str, bool)

    Raises
    ------
    RegistryError
        A plant whose id is a registered plant's that it is not, or a design of an unregistered class whose name is
        a registered design's id.
    """
    if kind == "plant":
        i = obj.id
        if not PLANTS.registered(i):
            return i, False
        try:
            registered = PLANTS.create(i)
        except Exception as exc:  # noqa: BLE001 - the catalog's factory failing: the object cannot be it
            registered = exc
        if not isinstance(registered, Exception) and _same_plant(obj, registered):
            return i, True
        raise RegistryError(
            f"plants: the Plant object's id {i!r} is the id of the registered plant {i!r} ({PLANTS[i].module}), and "
            f"the object is not that plant (its fields or what its f computes differ); give it another id, e.g. "
            f"dataclasses.replace(plant, id={(i + '_mine')!r})")
    i, registered = _design_id(obj)
    if not registered and DESIGNS.registered(i):
        raise RegistryError(
            f"designs: the {type(obj).__name__} object is named {i!r} (its class's name), which is the id of the "
            f"registered design {i!r} ({DESIGNS[i].module}); rename the class or register it "
            "(bench.register_design)")
    return i, registered
