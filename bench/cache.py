"""On-disk cache of finished pairs and plant constants, so that an interrupted run resumes.

``python -m bench run`` stores every finished pair (and every plant's constants) in
``.bench-cache/`` next to the report folder as soon as it finishes; a re-run takes what it
finds there instead of recomputing it, and ``--no-cache`` ignores the cache (neither reads nor
writes it). Delete the folder to reclaim the space.

Keys
----
An entry is found under the SHA-256 of a JSON document of everything its result depends on; a
change to any part is a miss. A pair's key holds:

- ``kind``: ``"pair"``;
- ``format``: :data:`CACHE_FORMAT`;
- ``versions``: the versions of Python and of the packages (:func:`bench.report.package_versions`);
- ``code``: the source of the shared code: ``bench.harness``, ``bench.estimators``,
  ``bench.cache`` and the modules they import (below);
- ``plant``: the plant's content: its registry id, every field of the :class:`plants.Plant`
  (A, B, C, x0, x_hat0 by exact bytes; t_final, params, family, the claimed and analytic
  constants, the channels, source and notes; f, the Jacobian and the channels' phi by name
  and module), a **probe** (below) of f and of the Jacobian, and the source of the module
  that registered the plant and of the modules defining f, the Jacobian and phi;
- ``design``: the design's content: id, every hyperparameter (the design object's dataclass
  fields, recursively through a pairing's parts), and the source of the modules defining it;
- ``options``: the run options that change results: seed, n_samples, use_claimed, t_final,
  noise, noise_dt and the simulation settings but ``max_wall_s`` (not ``timeout``,
  ``fail_fast``, ``jobs``: results do not depend on them);
- ``settings``: the suite's effective settings, read when the key is computed: the current
  value of every module-level constant named in upper case (``CONVERGED_RATIO``,
  ``_REL_TOL``) of every module whose source is in the key, when it is a number, a string,
  bytes, None, a numpy array, or a tuple, list, set, frozenset or string-keyed dict of those.
  A plugin that sets ``bench.metrics.CONVERGED_RATIO = 0.1`` therefore changes the keys of
  every pair of that run, the catalog's included.

A constants key holds ``kind`` (``"constants"``), ``format``, ``versions``, ``code``, ``plant``,
``settings``, ``seed`` and ``n_samples``.

"Source of a module" means the SHA-256 of its file, and is closed under imports: the source of
every module that a hashed module imports (at top level or inside a function, found by parsing
its source; absolute and relative imports) is hashed too, when the imported module is of the
project (``bench``, ``designs``, ``plants``, a plugin file) or is any other module whose file
lies outside the standard library and the installed packages (the ``stdlib``, ``platstdlib``,
``purelib`` and ``platlib`` paths of :mod:`sysconfig`, for this environment and its base
installation, and :func:`site.getsitepackages`, :func:`site.getusersitepackages`): a helper
module next to a plugin file (``import mylib``) is part of the key of every plant the plugin
defines with it. Installed packages enter through ``versions`` instead. So editing
``designs/thm1.py`` also invalidates Corollary 1, which imports helpers from it, and editing
``mylib.py`` invalidates the plugin's pairs. Rendering and command-line modules are left out
(``bench.report``, ``bench.cli``, ``bench.perf``, ``bench.__main__``; their imports are not
followed).

The probe evaluates f, seeded, at :data:`PROBE_POINTS` states (directions drawn once for the
dimension n, at 8 scales from 0.01 to 10, or from 5 % to 95 % of ``radius`` when the
constants or the channels hold only on a ball, the smallest radius given) plus x0 and x_hat0, as one batch (point by point if the
batch raises), and the Jacobian at each of them; the key holds the SHA-256 of the exact values
(every NaN the same; an exception or a non-numeric result is recorded by its type). A change of
f or of the Jacobian that hides in a closure is seen this way.

Entries
-------
``pairs/<key>.npz``: the record, the design result and the trajectory, as one JSON document
plus numpy arrays (``allow_pickle=False``: no pickled objects); ``constants/<key>.json``: a
:class:`bench.constants.ConstantsReport`. Each file is written to a temporary name and moved
into place with ``os.replace``, so an interrupted write leaves no partial entry; an unreadable
entry is a miss. Rows with status ``error`` or ``timeout`` are not stored (they may be
transient: a worker that died, a loaded machine).

A cache problem never fails a run: a key that cannot be computed, an unreadable entry, an
unwritable folder or an entry that cannot be stored is a miss (or an entry not stored), noted
in :attr:`Cache.errors`.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import os
import re
import site
import sys
import sysconfig
import tempfile
import warnings
from pathlib import Path
from typing import IO, Any, Callable

import numpy as np

__all__ = ["CACHE_FORMAT", "PROBE_POINTS", "Cache", "default_cache_dir"]

#: Bumped when the layout or the meaning of an entry changes.
CACHE_FORMAT = 3

#: Packages whose modules are hashed by source (plus plugin modules and local modules).
_PROJECT = ("bench", "designs", "plants")

#: Statuses that are never stored.
_TRANSIENT = ("error", "timeout")

#: The entries' files below the cache folder (``.format(key)``).
_PAIR_ENTRY = "pairs/{}.npz"
_CONSTANTS_ENTRY = "constants/{}.json"

#: Rendering and command-line modules: they do not change a pair's result, so editing them
#: does not invalidate the cache (their imports are not followed either).
_NOT_RESULTS = frozenset({"bench.report", "bench.cli", "bench.perf", "bench.__main__"})

#: Seeded probe states of f and of the Jacobian (8 directions x 8 scales), plus x0 and x_hat0.
PROBE_POINTS = 64
_PROBE_SEED = 7_2024
_PROBE_SCALES = 8

#: Module-level names read as settings: upper case, optionally with leading underscores.
_SETTING_NAME = re.compile(r"_*[A-Z][A-Z0-9_]*")


def default_cache_dir(out_dir: str | os.PathLike) -> Path:
    """``.bench-cache`` next to the report folder ``out_dir`` (its sibling)."""
    return Path(os.path.abspath(out_dir)).parent / ".bench-cache"


def _is_project(name: str) -> bool:
    """Whether a module belongs to the project (its packages or a plugin)."""
    return name.split(".")[0] in _PROJECT or name.startswith("oslbench_plugin_")


def _sha(data: bytes) -> str:
    """SHA-256 hex digest."""
    return hashlib.sha256(data).hexdigest()


# -- where a module lives -------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _installed_roots() -> tuple[str, ...]:
    """Folders of the standard library and of installed packages (this environment and its base)."""
    roots: set[str] = set()
    schemes: list[dict | None] = [None, {"base": sys.base_prefix, "platbase": sys.base_exec_prefix,
                                         "installed_base": sys.base_prefix,
                                         "installed_platbase": sys.base_exec_prefix}]
    for config in schemes:
        try:
            paths = sysconfig.get_paths(vars=config) if config else sysconfig.get_paths()
        except Exception:  # noqa: BLE001 - an odd installation: fewer roots
            continue
        roots.update(paths.get(k) for k in ("stdlib", "platstdlib", "purelib", "platlib"))
    for get in (getattr(site, "getsitepackages", None), getattr(site, "getusersitepackages", None)):
        try:
            found = get() if get is not None else []
        except Exception:  # noqa: BLE001 - some virtualenvs lack them
            continue
        roots.update([found] if isinstance(found, str) else found)
    out = set()
    for r in roots:
        if r:
            real = os.path.realpath(r)
            if os.path.dirname(real) != real:  # never the file system's root
                out.add(real)
    return tuple(sorted(out))


def _is_installed_file(path: str) -> bool:
    """True when ``path`` lies in the standard library or in an installed package's folder."""
    real = os.path.realpath(path)
    for root in _installed_roots():
        try:
            if os.path.commonpath([real, root]) == root:
                return True
        except ValueError:  # another drive
            continue
    return False


def _module_file(name: str) -> str | None:
    """The file of an imported module, or None."""
    mod = sys.modules.get(name)
    path = getattr(mod, "__file__", None) if mod is not None else None
    return path if isinstance(path, str) else None


def _find_file(name: str, near: str | None) -> str | None:
    """The file of module ``name`` without importing it: ``sys.modules``, else a search of the
    folder of the importing file ``near`` and of ``sys.path`` (packages level by level)."""
    if name in sys.modules:
        return _module_file(name)
    parts = name.split(".")
    search = ([os.path.dirname(near)] if near else []) + [p or os.getcwd() for p in sys.path if isinstance(p, str)]
    try:
        for i in range(len(parts)):
            prefix = ".".join(parts[: i + 1])
            if prefix in sys.modules:
                mod = sys.modules[prefix]
                spec_origin = _module_file(prefix)
                search = list(getattr(mod, "__path__", []) or [])
                if i == len(parts) - 1:
                    return spec_origin
                continue
            spec = importlib.machinery.PathFinder.find_spec(prefix, search)
            if spec is None:
                return None
            if i == len(parts) - 1:
                return spec.origin if spec.has_location else None
            search = list(spec.submodule_search_locations or [])
    except (ImportError, ValueError, OSError):
        return None
    return None


def _canon(v: Any, modules: set[str]) -> Any:
    """A JSON-able, exact description of a value (arrays by hash, floats by repr)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        modules.add(type(v).__module__)
        return {"__type__": f"{type(v).__module__}.{type(v).__qualname__}",
                **{f.name: _canon(getattr(v, f.name), modules) for f in dataclasses.fields(v)}}
    if isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        return {"__array__": [list(a.shape), str(a.dtype), _sha(a.tobytes())]}
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, (int, np.integer)):
        return int(v)
    if v is None or isinstance(v, str):
        return v
    if isinstance(v, (list, tuple)):
        return [_canon(x, modules) for x in v]
    if isinstance(v, dict):
        return {str(k): _canon(x, modules) for k, x in sorted(v.items(), key=lambda kv: str(kv[0]))}
    if callable(v):
        mod = getattr(v, "__module__", None)
        if mod:
            modules.add(mod)
        return {"__callable__": f"{mod}.{getattr(v, '__qualname__', type(v).__name__)}"}
    return {"__repr__": repr(v)}


class _Unsupported(Exception):
    """A module constant that is not a plain setting (skipped)."""


def _setting(v: Any, depth: int = 0) -> Any:
    """A JSON-able, exact description of a plain setting value; raises _Unsupported otherwise."""
    if depth > 6:
        raise _Unsupported
    if v is None or isinstance(v, (bool, np.bool_, str)):
        return bool(v) if isinstance(v, np.bool_) else v
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return {"f": repr(float(v))}
    if isinstance(v, (complex, np.complexfloating)):
        return {"c": [repr(v.real), repr(v.imag)]}
    if isinstance(v, bytes):
        return {"b": _sha(v)}
    if isinstance(v, np.ndarray):
        if v.dtype.hasobject:
            raise _Unsupported
        a = np.ascontiguousarray(v)
        return {"a": [list(a.shape), str(a.dtype), _sha(a.tobytes())]}
    if isinstance(v, (tuple, list)):
        return {type(v).__name__: [_setting(x, depth + 1) for x in v]}
    if isinstance(v, (set, frozenset)):
        items = [_setting(x, depth + 1) for x in v]
        return {"set": sorted(items, key=lambda x: json.dumps(x, sort_keys=True))}
    if isinstance(v, dict):
        if not all(isinstance(k, str) for k in v):
            raise _Unsupported
        return {"dict": {k: _setting(x, depth + 1) for k, x in sorted(v.items())}}
    raise _Unsupported


def _digest(raw: Any) -> str:
    """Hash of a numeric result, exact (every NaN alike); a non-numeric one by its type."""
    try:
        a = np.asarray(raw)
    except Exception as exc:  # noqa: BLE001 - an array-like that fails to convert
        return f"not an array: {type(exc).__name__}"
    if a.dtype.kind in "biuf":
        a = a.astype(np.float64)
        a = np.where(np.isnan(a), np.nan, a)
    elif a.dtype.kind == "c":
        a = a.astype(np.complex128)
        a = np.where(np.isnan(a.real) | np.isnan(a.imag), complex(np.nan, np.nan), a)
    else:
        return f"not numeric: {type(raw).__name__} {a.dtype}"
    return _sha(json.dumps([list(a.shape), str(a.dtype)]).encode() + np.ascontiguousarray(a).tobytes())


def _plain(v: Any) -> Any:
    """numpy scalars to Python scalars (for JSON)."""
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return v


def _atomic_write(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write a file whole or not at all: ``write(fh)`` into a temporary file, then rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:  # KeyboardInterrupt included: leave no temporary file behind
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


class Cache:
    """A folder of cached pairs and constants (see the module docstring).

    Parameters
    ----------
    root : path
        The cache folder (created on the first write).

    Attributes
    ----------
    hits, misses : int
        Pairs found / not found by :meth:`load_pair` (constants are counted in
        ``constants_hits`` / ``constants_misses``).
    stored : int
        Entries written.
    errors : list of str
        Problems met (a key that could not be computed, an unwritable folder, an unreadable
        entry); a cache problem never fails a run, it only costs a recomputation.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.hits = self.misses = self.constants_hits = self.constants_misses = self.stored = 0
        self.stored_pairs = 0
        self.errors: list[str] = []
        self._sources: dict[str, str] = {}
        self._deps: dict[str, set[str]] = {}
        self._paths: dict[str, str | None] = {}
        self._fixed: dict[str, Any] | None = None
        self._writable = True

    # -- fingerprints ------------------------------------------------------------------------
    def _path(self, name: str) -> str | None:
        """The file of module ``name`` (loaded, or found by :meth:`_imports` without importing it)."""
        return _module_file(name) or self._paths.get(name)

    def _source_hash(self, name: str) -> str:
        """The hash of a module's source (memoised)."""
        if name not in self._sources:
            path = self._path(name)
            if path is None:
                try:
                    spec = importlib.util.find_spec(name)
                    path = spec.origin if spec is not None and spec.has_location else None
                except (ImportError, ValueError):
                    path = None
            try:
                self._sources[name] = _sha(Path(path).read_bytes()) if path else "no source"
            except OSError:
                self._sources[name] = "unreadable source"
        return self._sources[name]

    def _local(self, name: str, near: str | None) -> bool:
        """True when module ``name`` is neither of the standard library nor installed (its file is found)."""
        top = name.split(".")[0]
        if top in sys.stdlib_module_names or top in sys.builtin_module_names:
            return False
        for mod in dict.fromkeys((top, name)):
            path = _find_file(mod, near)
            if path is None or _is_installed_file(path):
                return False
            if mod not in sys.modules:
                self._paths.setdefault(mod, path)
        return True

    def _imports(self, name: str) -> set[str]:
        """Project and local modules that module ``name`` imports anywhere in its source."""
        if name in self._deps:
            return self._deps[name]
        deps: set[str] = set()
        self._deps[name] = deps
        path = self._path(name)
        try:
            tree = ast.parse(Path(path).read_bytes()) if path else None
        except (OSError, SyntaxError, ValueError):
            tree = None
        if tree is None:
            return deps
        mod = sys.modules.get(name)
        is_pkg = (mod is not None and hasattr(mod, "__path__")) or (path or "").endswith("__init__.py")
        package = name if is_pkg else name.rpartition(".")[0]
        candidates: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    parts = a.name.split(".")
                    candidates.update(".".join(parts[: i + 1]) for i in range(len(parts)))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".") if package else []
                    if node.level - 1 > len(base) or (node.level - 1 == len(base) and not node.module):
                        continue
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if not target:
                    continue
                parts = target.split(".")
                candidates.update(".".join(parts[: i + 1]) for i in range(len(parts)))
                candidates.update(f"{target}.{a.name}" for a in node.names if a.name != "*")
        for cand in candidates:
            if cand == name:
                continue
            if _is_project(cand):
                if cand in sys.modules or self._is_module(cand):
                    deps.add(cand)
            elif self._local(cand, path):
                deps.add(cand)
        return deps

    @staticmethod
    def _is_module(name: str) -> bool:
        """Whether ``name`` can be imported."""
        try:
            return importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):
            return False

    def _code(self, roots: set[str]) -> dict[str, str]:
        """Source hashes of ``roots`` and every project or local module they import, transitively."""
        seen: set[str] = set()
        todo = [r for r in roots if r and (_is_project(r) or self._local(r, None))]
        while todo:
            name = todo.pop()
            if name in seen or name in _NOT_RESULTS:
                continue
            seen.add(name)
            if name not in sys.modules and _is_project(name):
                try:
                    importlib.import_module(name)
                except Exception:  # noqa: BLE001 - hashed as "no source" below
                    pass
            todo.extend(self._imports(name) - seen)
        return {name: self._source_hash(name) for name in sorted(seen)}

    @staticmethod
    def _settings(modules) -> dict[str, dict[str, Any]]:
        """The current values of the upper-case module constants of ``modules`` (see the module docstring)."""
        out: dict[str, dict[str, Any]] = {}
        for name in sorted(set(modules)):
            mod = sys.modules.get(name)
            if mod is None:
                continue
            values = {}
            for key, value in sorted(vars(mod).items()):
                if _SETTING_NAME.fullmatch(key):
                    try:
                        values[key] = _setting(value)
                    except _Unsupported:
                        pass
            if values:
                out[name] = values
        return out

    def _fixed_parts(self) -> dict[str, Any]:
        """The parts of every key that do not depend on the pair (format, versions, code; memoised)."""
        if self._fixed is None:
            from bench.report import package_versions

            self._fixed = {"format": CACHE_FORMAT, "versions": package_versions(),
                           "code": self._code({"bench.harness", "bench.estimators", "bench.cache"})}
        return self._fixed

    def _fingerprint(self, registry, kind: str, obj, obj_id: str, **extra) -> dict[str, Any]:
        """``{"id": obj_id, kind: obj canonical, **extra, "code": ...}``: the code is the source of the modules
        ``obj`` refers to and of the module that registered ``obj_id`` in ``registry`` (if any)."""
        modules: set[str] = set()
        data = {"id": obj_id, kind: _canon(obj, modules), **extra}
        try:
            modules.add(registry[obj_id].module)
        except KeyError:
            pass
        data["code"] = self._code(modules)
        return data

    def plant_fingerprint(self, plant, plant_id: str) -> dict[str, Any]:
        """The content of a plant (data, constants, a probe of f and of its Jacobian, and the source of its modules)."""
        from bench.registry import PLANTS

        # every field (arrays by exact bytes, callables by name and module, constants and channels
        # recursively), so a field added to Plant later is covered too
        return self._fingerprint(PLANTS, "plant", plant, plant_id, probe=self._probe(plant))

    @staticmethod
    def _probe_points(plant) -> np.ndarray:
        """Seeded states (n, PROBE_POINTS + 2): directions x scales (inside the constants' radius), x0, x_hat0."""
        n = plant.n
        rng = np.random.default_rng([_PROBE_SEED, n])
        D = rng.standard_normal((n, PROBE_POINTS))
        D /= np.maximum(np.linalg.norm(D, axis=0), 1e-300)
        radius = None
        for c in (getattr(plant, "bounds", None), getattr(plant, "claimed", None), getattr(plant, "channels", None)):
            r = getattr(c, "radius", None) if c is not None else None
            if r is not None and np.isfinite(r) and r > 0:
                radius = float(r) if radius is None else min(radius, float(r))
        scales = (np.geomspace(0.01, 10.0, _PROBE_SCALES) if radius is None
                  else radius * np.linspace(0.05, 0.95, _PROBE_SCALES))
        X = D * np.tile(scales, PROBE_POINTS // _PROBE_SCALES + 1)[:PROBE_POINTS]
        return np.concatenate([X, np.asarray(plant.x0, dtype=float)[:, None],
                               np.asarray(plant.x_hat0, dtype=float)[:, None]], axis=1)

    @classmethod
    def _probe(cls, plant) -> str:
        """Hash of f and of the Jacobian at the probe states (see the module docstring)."""

        def call(fn, x) -> str:
            try:
                return _digest(fn(x.copy()))
            except Exception as exc:  # noqa: BLE001 - the harness reports a broken f; the key only notes it
                return f"raised {type(exc).__name__}"

        X = cls._probe_points(plant)
        parts: list[str] = []
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            batch = call(plant.f, X)
            if batch.startswith("raised"):  # point by point, each failure noted
                parts.append("f by point: " + ",".join(call(plant.f, X[:, j]) for j in range(X.shape[1])))
            else:
                parts.append("f batch: " + batch)
            jac = getattr(plant, "jacobian", None)
            if jac is not None:
                parts.append("jacobian: " + ",".join(call(jac, X[:, j]) for j in range(X.shape[1])))
        return _sha("\n".join(parts).encode())

    def design_fingerprint(self, design, design_id: str) -> dict[str, Any]:
        """The content of a design (hyperparameters, recursively, and the source of its modules)."""
        from bench.registry import DESIGNS

        return self._fingerprint(DESIGNS, "design", design, design_id)

    @staticmethod
    def _options(options) -> dict[str, Any]:
        """The run options that change a pair's result, canonical (not the wall-clock limits)."""
        sim = {f.name: _canon(getattr(options.sim, f.name), set()) for f in dataclasses.fields(options.sim)
               if f.name != "max_wall_s"}
        return {"seed": options.seed, "n_samples": options.n_samples, "use_claimed": options.use_claimed,
                "t_final": _canon(options.t_final, set()), "noise": _canon(options.noise, set()),
                "noise_dt": _canon(options.noise_dt, set()), "sim": sim}

    def _key(self, doc: dict) -> str:
        """The key of a document: SHA-256 of its canonical JSON."""
        return _sha(json.dumps(doc, sort_keys=True).encode())

    def _safe_key(self, what: str, build: Callable[[], dict]) -> str | None:
        """The key of ``build()``, or None with the problem noted."""
        try:
            return self._key(build())
        except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run: no key, a miss
            self.errors.append(f"cannot compute the cache key of {what}: {type(exc).__name__}: {exc}")
            return None

    def pair_key(self, plant, plant_id: str, design, design_id: str, options) -> str | None:
        """The key of one pair (see the module docstring); None when it cannot be computed (then a miss)."""

        def build() -> dict:
            fixed = self._fixed_parts()
            p = self.plant_fingerprint(plant, plant_id)
            d = self.design_fingerprint(design, design_id)
            return {"kind": "pair", **fixed, "plant": p, "design": d, "options": self._options(options),
                    "settings": self._settings([*fixed["code"], *p["code"], *d["code"]])}

        return self._safe_key(f"{plant_id} x {design_id}", build)

    def constants_key(self, plant, plant_id: str, options) -> str | None:
        """The key of one plant's constants (plant content, seed, n_samples, code, settings, versions);
        None when it cannot be computed (then a miss)."""

        def build() -> dict:
            fixed = self._fixed_parts()
            p = self.plant_fingerprint(plant, plant_id)
            return {"kind": "constants", **fixed, "plant": p, "seed": options.seed, "n_samples": options.n_samples,
                    "settings": self._settings([*fixed["code"], *p["code"]])}

        return self._safe_key(f"the constants of {plant_id}", build)

    # -- storage ------------------------------------------------------------------------------
    def _write(self, path: Path, write: Callable[[IO[bytes]], None]) -> bool:
        """Write an entry atomically; False (noted) when the cache cannot be written."""
        if not self._writable:
            return False
        try:
            _atomic_write(path, write)
        except OSError as exc:  # an unwritable folder, a full disk: run on without the cache
            self._writable = False
            self.errors.append(f"cannot write the cache {self.root}: {exc}")
            return False
        except Exception as exc:  # noqa: BLE001 - a value the writer cannot store: this entry only
            self.errors.append(f"cannot store {path.name} in the cache: {type(exc).__name__}: {exc}")
            return False
        self.stored += 1
        return True

    def _guard(self, what: str, fn: Callable[[], Any], default: Any) -> Any:
        """``fn()``, or ``default`` with the problem noted: a cache problem never fails a run."""
        try:
            return fn()
        except Exception as exc:  # noqa: BLE001
            self.errors.append(f"cache: {what}: {type(exc).__name__}: {exc}")
            return default

    def _stored(self, what: str, store: Callable[[str, Any], bool], key: str | None, value) -> bool:
        """``store(key, value)`` guarded; False without a key."""
        if not key:
            return False
        return self._guard(f"cannot store {what}", lambda: store(key, value), False)

    def _loaded(self, entry: str, read: Callable[[Path], Any], key: str | None, tally: str):
        """``read(path)`` of the entry ``entry.format(key)``, or None: no key, no entry, or an entry that cannot
        be read (noted: a damaged entry is a miss). Counted in the attribute ``tally + "hits"`` or
        ``tally + "misses"``."""
        value = None
        if key:
            path = self.root / entry.format(key)
            try:
                if path.is_file():
                    value = read(path)
            except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run
                self.errors.append(f"unreadable cache entry {path.name}: {type(exc).__name__}: {exc}")
        counter = tally + ("misses" if value is None else "hits")
        setattr(self, counter, getattr(self, counter) + 1)
        return value

    def store_pair(self, key: str | None, outcome) -> bool:
        """Store a finished pair; False when it is not cacheable (error, timeout, no key) or not written."""
        return self._stored("a pair", self._store_pair, key, outcome)

    def load_pair(self, key: str | None):
        """The cached :class:`bench.harness.PairOutcome` (without its plant), or None; counts hits/misses."""
        return self._loaded(_PAIR_ENTRY, self._read_pair, key, tally="")

    def store_constants(self, key: str | None, report) -> bool:
        """Store a plant's :class:`bench.constants.ConstantsReport`; False when not written (or no key)."""
        return self._stored("constants", self._store_constants, key, report)

    def load_constants(self, key: str | None):
        """The cached :class:`bench.constants.ConstantsReport`, or None; counts constants hits/misses."""
        return self._loaded(_CONSTANTS_ENTRY, self._read_constants, key, tally="constants_")

    def _store_pair(self, key: str, outcome) -> bool:
        """Store a pair's record, result, certificate and trajectory as one .npz (no pickling)."""
        rec = outcome.record
        if rec.get("status") in _TRANSIENT:
            return False
        arrays: dict[str, np.ndarray] = {}
        meta: dict[str, Any] = {"format": CACHE_FORMAT, "record": {k: _plain(v) for k, v in rec.items()},
                                "result": None, "trajectory": None, "certificate": None}
        res = outcome.result
        if res is not None:
            skip = ("K", "F", "estimator", "certificate")
            d = {f.name: getattr(res, f.name) for f in dataclasses.fields(res) if f.name not in skip}
            d["min_eig"] = {k: _plain(v) for k, v in d["min_eig"].items()}
            d["params"] = {k: _plain(v) for k, v in d["params"].items()}
            est = res.estimator
            if est is not None:
                if not dataclasses.is_dataclass(est):
                    return False  # cannot be rebuilt without pickling
                d["estimator"] = {"type": [type(est).__module__, type(est).__qualname__],
                                  "fields": {k: _plain(v) for k, v in dataclasses.asdict(est).items()}}
            if res.certificate is not None:
                d["certificate"] = {k: _plain(v) for k, v in res.certificate.items() if k != "P"}
                arrays["design_cert_P"] = np.asarray(res.certificate["P"], dtype=float)
            meta["result"] = d
            for name in ("K", "F"):
                if getattr(res, name) is not None:
                    arrays[name] = np.asarray(getattr(res, name), dtype=float)
        cert = outcome.certificate
        if cert is not None:
            meta["certificate"] = {lv: {f.name: _plain(getattr(r, f.name)) for f in dataclasses.fields(r) if f.name != "P"}
                                   for lv, r in cert.levels.items()}
            arrays.update({f"P_{lv}": np.asarray(r.P, dtype=float) for lv, r in cert.levels.items() if r.P is not None})
        tr = outcome.trajectory
        if tr is not None:
            meta["trajectory"] = {"status": tr.status, "message": tr.message, "wall_s": tr.wall_s, "nfev": int(tr.nfev)}
            arrays.update(t=tr.t, x=tr.x, x_hat=tr.x_hat, u=tr.u)
        try:
            text = json.dumps(meta, default=repr)
        except (TypeError, ValueError):
            return False
        arrays["meta"] = np.array(text)
        ok = self._write(self.root / _PAIR_ENTRY.format(key), lambda fh: np.savez_compressed(fh, **arrays))
        self.stored_pairs += int(ok)
        return ok

    @staticmethod
    def _read_pair(path: Path):
        """Rebuild a :class:`bench.harness.PairOutcome` from an .npz entry (None when of another format)."""
        from bench.certify import Certificate, LevelResult
        from bench.harness import COLUMNS, PairOutcome
        from bench.simulate import Trajectory
        from designs import DesignResult

        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
        if meta.get("format") != CACHE_FORMAT or set(meta["record"]) != set(COLUMNS):
            return None
        rec = {c: meta["record"][c] for c in COLUMNS}
        result = None
        if meta["result"] is not None:
            d = dict(meta["result"])
            est = d.pop("estimator", None)
            if est is not None:
                mod, qual = est["type"]
                obj: Any = importlib.import_module(mod)
                for part in qual.split("."):
                    obj = getattr(obj, part)
                est = obj(**est["fields"])
            dcert = d.pop("certificate", None)
            if dcert is not None:
                dcert = {**dcert, "P": arrays["design_cert_P"]}
            result = DesignResult(**d, K=arrays.get("K"), F=arrays.get("F"), estimator=est, certificate=dcert)
        traj = None
        if meta["trajectory"] is not None:
            tm = meta["trajectory"]
            traj = Trajectory(arrays["t"], arrays["x"], arrays["x_hat"], arrays["u"], tm["status"], tm["message"],
                              tm["wall_s"], tm["nfev"])
        cert = None
        if meta.get("certificate") is not None:
            cert = Certificate({lv: LevelResult(**f, P=arrays.get(f"P_{lv}")) for lv, f in meta["certificate"].items()})
        return PairOutcome(rec, result=result, trajectory=traj, certificate=cert)

    def _store_constants(self, key: str, report) -> bool:
        """Store a constants report as JSON."""
        try:
            text = json.dumps({"format": CACHE_FORMAT, **report.to_dict()}).encode()
        except (TypeError, ValueError):
            return False
        return self._write(self.root / _CONSTANTS_ENTRY.format(key), lambda fh: fh.write(text))

    @staticmethod
    def _read_constants(path: Path):
        """A :class:`bench.constants.ConstantsReport` from a .json entry (None when of another format)."""
        from bench.constants import ConstantsReport

        doc = json.loads(path.read_text(encoding="utf-8"))
        return ConstantsReport.from_dict(doc) if doc.get("format") == CACHE_FORMAT else None
