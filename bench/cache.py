"""On-disk cache of finished pairs and plant constants, so that an interrupted run resumes.

``python -m bench run`` stores every finished pair and every plant's constants in ``.bench-cache/``
beside the report folder; a re-run reuses them (``--no-cache``: neither read nor written).

An entry's key is the SHA-256 of a JSON document of what its result depends on:
``kind`` (``"pair"`` or ``"constants"``), ``format`` (:data:`CACHE_FORMAT`), ``versions`` (Python and
packages), ``code`` (the SHA-256 of every source file of bench/, designs/, plants/, of the registered
plugin files, of the other non-installed files defining what the pair refers to, and of the loaded
modules beside them), ``plant`` (its ``id``, every field in ``plant``, and a ``probe``: the SHA-256
of f and its Jacobian at :data:`PROBE_POINTS` seeded states, x0 and x_hat0), ``design`` (``id`` and
every hyperparameter in ``design``), ``options`` (pairs: the run options but the wall-clock limits)
or ``seed`` and ``n_samples`` (constants).

Entries are ``pairs/<key>.npz`` and ``constants/<key>.npz``: the object's dataclass fields as JSON,
its arrays, and a SHA-256 of both, read with ``allow_pickle=False`` and written atomically. Rows with
status ``error`` or ``timeout`` are not stored. A cache problem never fails a run: a damaged entry
or an unwritable folder is a miss, noted in :attr:`Cache.errors`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import json
import os
import sys
import sysconfig
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench.lmi import digest
from bench.outdir import atomic_write as _atomic_write, sha_file as _sha_file

__all__ = ["Cache"]

#: Bumped when the layout or the meaning of an entry changes.
CACHE_FORMAT = 4

#: Seeded probe states of f and of the Jacobian (8 directions x 8 scales), plus x0 and x_hat0.
PROBE_POINTS = 64
_PROBE_SEED = 7_2024
_PROBE_SCALES = 8

_PROJECT = ("bench", "designs", "plants")
_PLUGIN_MODULE = "oslbench_plugin_"  # how bench.plugins names the module of a plugin file
_TRANSIENT = ("error", "timeout")
#: Option fields that do not change a result (wall-clock limits, stopping at the first failure).
_NOT_RESULTS = ("timeout", "fail_fast", "max_wall_s")
_INSTALLED = tuple(sorted({os.path.realpath(p) for k, p in sysconfig.get_paths().items()
                           if k in ("stdlib", "platstdlib", "purelib", "platlib")}))


def default_cache_dir(out_dir: str | os.PathLike) -> Path:
    """``.bench-cache`` next to the report folder ``out_dir`` (its sibling)."""
    return Path(os.path.abspath(out_dir)).parent / ".bench-cache"


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


_realpath = functools.lru_cache(maxsize=None)(os.path.realpath)


def _outside_file(module: str) -> str | None:
    """The file of a loaded module that is neither of the project nor installed, else None."""
    if module.split(".")[0] in _PROJECT:
        return None
    path = getattr(sys.modules.get(module), "__file__", None)
    if not isinstance(path, str):
        return None
    real = _realpath(path)
    return None if real.startswith(tuple(r + os.sep for r in _INSTALLED)) else real


def _encode(v: Any, arrays: dict[str, np.ndarray], modules: set[str] | None = None) -> Any:
    """JSON for ``v``, reversible (arrays into ``arrays``; TypeError for what needs a pickle), or with ``modules``
    exact for a key (every dataclass field, arrays by hash, callables by name, the rest by repr; modules met added)."""
    key = modules is not None
    if isinstance(v, np.ndarray) and not v.dtype.hasobject:
        if key:
            a = np.ascontiguousarray(v)
            return {"__array__": [list(a.shape), str(a.dtype), _sha(a.tobytes())]}
        name = f"a{len(arrays)}"
        arrays[name] = v
        return {"__array__": name}
    if isinstance(v, np.generic):
        return _encode(v.item(), arrays, modules)
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        if key:
            modules.add(type(v).__module__)
        return {"__dataclass__": f"{type(v).__module__}:{type(v).__qualname__}",
                "fields": {f.name: _encode(getattr(v, f.name), arrays, modules)
                           for f in dataclasses.fields(v) if f.init or key}}
    if isinstance(v, dict) and (key or all(isinstance(k, str) for k in v)):
        return {"__dict__": {str(k): _encode(x, arrays, modules) for k, x in v.items()}}
    if isinstance(v, tuple):
        return {"__tuple__": [_encode(x, arrays, modules) for x in v]}
    if isinstance(v, list):
        return [_encode(x, arrays, modules) for x in v]
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, complex):  # an eigenvalue of a witness
        return {"__complex__": [v.real, v.imag]}
    if not key:
        raise TypeError(f"a {type(v).__name__} cannot be stored without pickling")
    if callable(v):
        modules.add(getattr(v, "__module__", None) or "")
        return {"__callable__": f"{getattr(v, '__module__', None)}.{getattr(v, '__qualname__', type(v).__name__)}"}
    return {"__repr__": repr(v)}


def _decode(v: Any, arrays: dict[str, np.ndarray]) -> Any:
    """The value :func:`_encode` described; dataclass types only, from project or loaded modules."""
    if isinstance(v, list):
        return [_decode(x, arrays) for x in v]
    if not isinstance(v, dict):
        return v
    if "__array__" in v:
        return arrays[v["__array__"]]
    if "__tuple__" in v:
        return tuple(_decode(x, arrays) for x in v["__tuple__"])
    if "__dict__" in v:
        return {k: _decode(x, arrays) for k, x in v["__dict__"].items()}
    if "__complex__" in v:
        return complex(*v["__complex__"])
    mod, qual = v["__dataclass__"].split(":")
    obj: Any = importlib.import_module(mod) if mod.split(".")[0] in _PROJECT else sys.modules[mod]
    for part in qual.split("."):
        obj = getattr(obj, part)
    if not (isinstance(obj, type) and dataclasses.is_dataclass(obj)):
        raise TypeError(f"{v['__dataclass__']} is not a dataclass")
    return obj(**{k: _decode(x, arrays) for k, x in v["fields"].items()})


def _checksum(meta: str, arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256(meta.encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name} {a.dtype.str} {a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _check_record(rec: Any) -> None:
    """ValueError unless ``rec`` has the record's columns, each of the kind of its blank value."""
    from bench.pipeline import COLUMNS, blank_record

    if not isinstance(rec, dict) or list(rec) != list(COLUMNS):
        raise ValueError("the record's columns are not the suite's")
    for col, blank in blank_record("", "").items():
        v = rec[col]
        ok = (isinstance(v, str) if isinstance(blank, str)
              else v is None or isinstance(v, bool) if blank is None or isinstance(blank, bool)
              else v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)))
        if not ok:
            raise ValueError(f"column {col!r} holds {v!r}")


class Cache:
    """A folder of cached pairs and constants (see the module docstring).

    Parameters
    ----------
    root : path
        The cache folder (created on the first write).

    Attributes
    ----------
    hits, misses, stored : int
        Pairs found and not found, entries written.
    errors : list of str
        Problems met (a key not computed, an unwritable folder, a damaged entry by its path).
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.hits = self.misses = self.stored = 0
        self.errors: list[str] = []
        self._files: dict[str, str] = {}
        self._project: dict[str, str] | None = None
        self._versions: dict[str, str] | None = None
        self._writable = True

    def _code(self, modules: set[str]) -> dict[str, str]:
        """The ``code`` part of a key (module docstring)."""
        if self._project is None:
            self._project = {}
            for pkg in _PROJECT:
                folder = Path(importlib.import_module(pkg).__file__).parent
                for p in sorted(folder.rglob("*.py")):
                    self._project[f"{pkg}/{p.relative_to(folder).as_posix()}"] = _sha_file(str(p))
        from bench.registry import DESIGNS, PLANTS

        plugins = {m for reg in (PLANTS, DESIGNS) for i in reg.ids() if (m := reg[i].module).startswith(_PLUGIN_MODULE)}
        files = {f for m in plugins | modules if (f := _outside_file(m))}
        if files:
            folders = tuple({os.path.dirname(f) + os.sep for f in files})
            files |= {f for m in list(sys.modules) if (f := _outside_file(m)) and f.startswith(folders)}
        for f in files - self._files.keys():
            self._files[f] = _sha_file(f)
        return {**self._project, **{f: self._files[f] for f in sorted(files)}}

    def plant_fingerprint(self, plant, plant_id: str) -> dict[str, Any]:
        """The plant's id, fields and probe (see the module docstring), and the modules it refers to."""
        modules: set[str] = set()
        return {"id": plant_id, "plant": _encode(plant, {}, modules), "probe": self._probe(plant), "modules": modules}

    @staticmethod
    def _probe_points(plant) -> np.ndarray:
        """Seeded states (n, PROBE_POINTS + 2): directions x scales (inside the constants' radius), x0, x_hat0."""
        rng = np.random.default_rng([_PROBE_SEED, plant.n])
        D = rng.standard_normal((plant.n, PROBE_POINTS))
        D /= np.maximum(np.linalg.norm(D, axis=0), 1e-300)
        radii = [r for c in (plant.bounds, plant.claimed, plant.channels)
                 if (r := getattr(c, "radius", None)) is not None and np.isfinite(r) and r > 0]
        scales = (np.geomspace(0.01, 10.0, _PROBE_SCALES) if not radii
                  else min(radii) * np.linspace(0.05, 0.95, _PROBE_SCALES))
        X = D * np.tile(scales, PROBE_POINTS // _PROBE_SCALES)
        return np.concatenate([X, np.asarray(plant.x0, dtype=float)[:, None],
                               np.asarray(plant.x_hat0, dtype=float)[:, None]], axis=1)

    @classmethod
    def _probe(cls, plant) -> str:
        """Hash of f and of the Jacobian at the probe states (an exception is recorded by its type)."""

        def call(fn, x) -> str:
            try:
                return digest(fn(x.copy()))
            except Exception as exc:  # noqa: BLE001 - the harness reports a broken f; the key only notes it
                return f"raised {type(exc).__name__}"

        X = cls._probe_points(plant)
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            parts = [call(plant.f, X)]
            if parts[0].startswith("raised"):
                parts += [call(plant.f, X[:, j]) for j in range(X.shape[1])]
            if plant.jacobian is not None:
                parts += [call(plant.jacobian, X[:, j]) for j in range(X.shape[1])]
        return _sha("\n".join(parts).encode())

    def _key(self, doc: dict) -> str:
        """The key of a document: SHA-256 of its canonical JSON."""
        return _sha(json.dumps(doc, sort_keys=True).encode())

    def _build_key(self, what: str, kind: str, plant, plant_id: str, **parts) -> str | None:
        """The key of an entry, or None with the problem noted (then a miss)."""
        try:
            if self._versions is None:
                from bench.report import package_versions

                self._versions = package_versions()
            p = self.plant_fingerprint(plant, plant_id)
            modules = p.pop("modules")
            if "design" in parts:
                design, design_id = parts.pop("design")
                parts["design"] = {"id": design_id, "design": _encode(design, {}, modules)}
            return self._key({"kind": kind, "format": CACHE_FORMAT, "versions": self._versions,
                              "code": self._code(modules), "plant": p, **parts})
        except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run: no key, a miss
            self.errors.append(f"cannot compute the cache key of {what}: {type(exc).__name__}: {exc}")
            return None

    def pair_key(self, plant, plant_id: str, design, design_id: str, options) -> str | None:
        """The key of one pair (see the module docstring); None when it cannot be computed."""
        opts = {f.name: getattr(options, f.name) for f in dataclasses.fields(options) if f.name not in _NOT_RESULTS}
        opts["sim"] = {k: v for k, v in dataclasses.asdict(options.sim).items() if k not in _NOT_RESULTS}
        return self._build_key(f"{plant_id} x {design_id}", "pair", plant, plant_id, design=(design, design_id),
                               options=_encode(opts, {}, set()))

    def constants_key(self, plant, plant_id: str, options) -> str | None:
        """The key of one plant's constants; None when it cannot be computed."""
        return self._build_key(f"the constants of {plant_id}", "constants", plant, plant_id, seed=options.seed,
                               n_samples=options.n_samples)

    def _store(self, folder: str, key: str | None, obj) -> bool:
        """Write ``obj`` as the entry ``folder/<key>.npz``; False (noted) when it cannot be stored."""
        if not key or not self._writable:
            return False
        path = self.root / folder / f"{key}.npz"
        try:
            arrays: dict[str, np.ndarray] = {}
            meta = json.dumps({"format": CACHE_FORMAT, "value": _encode(obj, arrays)})
            payload = {**arrays, "meta": np.array(meta), "sha256": np.array(_checksum(meta, arrays))}
            _atomic_write(path, lambda fh: np.savez_compressed(fh, **payload))
        except OSError as exc:  # an unwritable folder, a full disk: run on without the cache
            self._writable = False
            self.errors.append(f"cannot write the cache {self.root}: {exc}")
            return False
        except Exception as exc:  # noqa: BLE001 - a value that cannot be stored: this entry only
            self.errors.append(f"cannot store {path} in the cache: {type(exc).__name__}: {exc}")
            return False
        self.stored += 1
        return True

    def _load(self, folder: str, key: str | None, expected: type, check: Callable[[Any], None] | None = None):
        """The object of the entry ``folder/<key>.npz``, or None (a damaged entry noted by its path)."""
        if not key:
            return None
        path = self.root / folder / f"{key}.npz"
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            meta, sha = str(arrays.pop("meta")), str(arrays.pop("sha256"))
            if _checksum(meta, arrays) != sha:
                raise ValueError("its checksum does not match its content")
            doc = json.loads(meta)
            if doc.get("format") != CACHE_FORMAT:
                return None
            obj = _decode(doc["value"], arrays)
            if not isinstance(obj, expected):
                raise TypeError(f"it holds a {type(obj).__name__}, not a {expected.__name__}")
            if check is not None:
                check(obj)
            return obj
        except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run
            self.errors.append(f"damaged cache entry {path} ignored (recomputed): {type(exc).__name__}: {exc}")
            return None

    def store_pair(self, key: str | None, outcome) -> bool:
        """Store a finished pair (not its plant); False when not cacheable (error, timeout, no key) or not written."""
        if outcome.record.get("status") in _TRANSIENT:
            return False
        return self._store("pairs", key, dataclasses.replace(outcome, plant=None))

    def load_pair(self, key: str | None):
        """The cached :class:`bench.pipeline.PairOutcome` (without its plant), or None; counts hits/misses."""
        from bench.pipeline import PairOutcome

        out = self._load("pairs", key, PairOutcome, lambda o: _check_record(o.record))
        self.hits += out is not None
        self.misses += out is None
        return out

    def store_constants(self, key: str | None, report) -> bool:
        """Store a plant's :class:`bench.constants.ConstantsReport`; False when not written (or no key)."""
        return self._store("constants", key, report)

    def load_constants(self, key: str | None):
        """The cached :class:`bench.constants.ConstantsReport`, or None."""
        from bench.constants import ConstantsReport

        return self._load("constants", key, ConstantsReport)
