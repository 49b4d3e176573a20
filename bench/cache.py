"""On-disk cache of finished pairs and plant constants, so that an interrupted run resumes.

``python -m bench run`` stores every finished pair and every plant's constants in ``.bench-cache/``
beside the report folder; a re-run reuses them (``--no-cache``: neither read nor written). A run from
the cache reports what a ``--no-cache`` run would: the key and the pair's digest cover every callable
of the plant wherever the run's own checks evaluate it.

An entry's key is the SHA-256 of a JSON document of what its result depends on:
``kind`` (``"pair"`` or ``"constants"``), ``format`` (:data:`CACHE_FORMAT`), ``versions`` (Python and
packages), ``code`` (the SHA-256 of every source file of bench/, designs/, plants/, of the registered
plugin files, of the other non-installed files defining what the pair refers to, and of the loaded
modules beside them), ``plant`` (its ``id``, every field in ``plant`` (callables by name, ``params`` and
``notes`` by value), and a ``probe``: the SHA-256 of what f, its Jacobian, the channels' phi and
narrowing compute at seeded states (:data:`PROBE_POINTS` inside the constants' radius, as many out to
the samplers' reach :func:`bench.constants.sampled_range`, x0 and x_hat0), phi at H x of those states
and along each channel's axis, the narrowing at radii out to the channels' reach and at the regions of
the search from x0), ``design`` (``id`` and every hyperparameter in ``design``), ``options`` (pairs: the
run options but the wall-clock limits) or ``seed`` and ``n_samples`` (constants).

A pair's checks look further than the key can know beforehand: along its simulation and out to
:data:`bench.constants.REACH_FACTOR` times the largest state it reached. A stored pair therefore carries
its ``checked`` reach (that, at least the samplers' reach) and a digest of the same callables at seeded
states out to it, at instants of its trajectory and at its witnesses' states; on load the digest is
recomputed with the plant the key was computed from, and a different one (f changed only far away) is a
miss, not an error.

What the key cannot see: a plant's callables that read anything else (a file, an environment variable, a
global changed between runs) give the same probe while computing something else elsewhere. Such a plugin
must say what it read in the plant: a version number in ``params`` (e.g. ``params={"c": c,
"table_version": 3}``) or a version string or the file's SHA-256 in ``notes``, both of which enter the
key by value; or run with ``--no-cache``.

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

from bench.constants import REACH_FACTOR, sampled_range
from bench.lmi import digest
from bench.outdir import atomic_write as _atomic_write, sha_file as _sha_file

__all__ = ["Cache"]

#: Bumped when the layout or the meaning of an entry changes.
CACHE_FORMAT = 5

#: Seeded probe states of a key, per block (8 directions x 8 scales; :meth:`Cache._probe_points`).
PROBE_POINTS = 64
_PROBE_SEED = 7_2024
_PROBE_SCALES = 8
#: Radii at which a channel narrowing is probed (geometric), beside the regions of the search from x0.
_NARROW_RADII = 16
#: Instants of a trajectory, and states at which the Jacobian is evaluated, in a pair's own digest.
_TRAJECTORY_POINTS = 64
_JACOBIAN_POINTS = 16

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


def _ball(n: int, scales: np.ndarray, stream: int) -> np.ndarray:
    """Seeded states (n, PROBE_POINTS): PROBE_POINTS / len(scales) unit directions of the seed ``stream``, each at every
    scale."""
    rng = np.random.default_rng([_PROBE_SEED, n, stream])
    D = rng.standard_normal((n, PROBE_POINTS))
    D /= np.maximum(np.linalg.norm(D, axis=0), 1e-300)
    return D * np.tile(scales, PROBE_POINTS // len(scales))


def _reach_scales(reach: float) -> np.ndarray:
    """The scales of a probe out to ``||x|| <= reach``: geometric from 1."""
    return np.geomspace(1.0, max(reach, 1.0), _PROBE_SCALES)


def _channel_reach(plant, reach: float) -> np.ndarray:
    """How far each channel's input goes when x goes out to ``reach`` (as the channel sampler,
    :func:`bench.constants._channel_check`: ``max(reach ||H_i||, reach)``); empty without channels."""
    ch = plant.channels
    return np.empty(0) if ch is None else np.maximum(reach * np.linalg.norm(ch.H, axis=1), reach)


def _narrow_radii(plant, reach: float) -> np.ndarray:
    """The radii at which a channel narrowing is probed: geometric out to the channels' reach, and the regions of
    the search from x0 (:func:`bench.certify.certify_from_x0`); empty without a narrowing."""
    from bench.certify import FROM_X0_GROWTH, FROM_X0_STEPS, _region_rows

    ch = plant.channels
    if ch is None or ch.narrow is None:
        return np.empty(0)
    z0 = np.concatenate([plant.x0, plant.x0 - plant.x_hat0])
    r0 = max(float(np.abs(_region_rows(ch.H) @ z0).max()), 1e-3)
    regions = r0 * FROM_X0_GROWTH ** np.arange(1, FROM_X0_STEPS + 1)
    return np.concatenate([np.geomspace(1e-3, _channel_reach(plant, reach).max(), _NARROW_RADII), regions])


def _call(fn, *args) -> str:
    """The digest of ``fn(*args)``, or how it raised (the harness reports a broken callable; a key only notes it)."""
    try:
        return digest(fn(*(a.copy() if isinstance(a, np.ndarray) else a for a in args)))
    except Exception as exc:  # noqa: BLE001 - see above
        return f"raised {type(exc).__name__}"


def _fingerprint(plant, X: np.ndarray, radii: np.ndarray, jacobian_points: int | None = None) -> str:
    """SHA-256 of what every callable of the plant computes: f at the states ``X`` (n, N) (column by column if the
    batch raises), the Jacobian at each of them (or at ``jacobian_points`` of them, evenly spread), the channels'
    phi at ``H X`` and along each channel's axis out to its reach, the narrowing at ``radii``."""
    reach = float(np.linalg.norm(X, axis=0).max(initial=1.0))
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        parts = [_call(plant.f, X)]
        if parts[0].startswith("raised"):
            parts += [_call(plant.f, X[:, j]) for j in range(X.shape[1])]
        if plant.jacobian is not None:
            cols = range(X.shape[1]) if jacobian_points is None else np.unique(
                np.linspace(0, X.shape[1] - 1, jacobian_points).astype(int))
            parts += [_call(plant.jacobian, X[:, j]) for j in cols]
        ch = plant.channels
        if ch is not None:
            s = np.geomspace(1e-2, 1.0, _PROBE_SCALES)
            axes = [np.outer(np.eye(ch.q)[i], np.concatenate([s, -s]) * z) for i, z in
                    enumerate(_channel_reach(plant, reach))]
            parts += [_call(ch.phi, np.asarray(ch.H, dtype=float) @ X), _call(ch.phi, np.concatenate(axes, axis=1))]
            parts += [_call(lambda r: np.concatenate([np.ravel(b) for b in ch.narrow(r)]), float(r)) for r in radii]
    return _sha("\n".join(parts).encode())


def _pair_states(plant, outcome) -> tuple[float, np.ndarray]:
    """How far a pair's own checks looked (its reach: the samplers' reach, and :data:`bench.constants.REACH_FACTOR`
    times the largest state its simulation or its witnesses reached) and the states its digest evaluates: seeded
    directions out to that reach, :data:`_TRAJECTORY_POINTS` instants of the trajectory (x and x_hat), the witnesses."""
    n = plant.n
    seen = [np.zeros((n, 0))]
    tr = outcome.trajectory
    if tr is not None:
        X, XH = (np.asarray(v, dtype=float).reshape(n, -1) for v in (tr.x, tr.x_hat))
        keep = np.all(np.isfinite(X), axis=0) & np.all(np.isfinite(XH), axis=0)
        idx = np.flatnonzero(keep)[np.unique(np.linspace(0, keep.sum() - 1, _TRAJECTORY_POINTS).astype(int))] \
            if keep.any() else []
        seen += [X[:, idx], XH[:, idx]]
    for w in getattr(outcome.certificate, "witnesses", None) or ():
        z = getattr(w, "z", None)
        if z is not None and np.all(np.isfinite(z)):
            x, e = np.split(np.asarray(z, dtype=float), 2)
            seen.append(np.stack([x, x - e], axis=1))
    S = np.concatenate(seen, axis=1)
    reach = max(sampled_range(plant), REACH_FACTOR * float(np.linalg.norm(S, axis=0).max(initial=0.0)))
    return reach, np.concatenate([_ball(n, _reach_scales(reach), 2), S], axis=1)


def _pair_digest(plant, outcome) -> dict[str, Any]:
    """``{"reach", "digest"}`` of a pair: :func:`_fingerprint` at :func:`_pair_states` (module docstring)."""
    reach, X = _pair_states(plant, outcome)
    return {"reach": reach, "digest": _fingerprint(plant, X, _narrow_radii(plant, reach), _JACOBIAN_POINTS)}


def _check_record(rec: Any) -> None:
    """ValueError unless ``rec`` has the record's columns, each of the kind of its blank value."""
    from bench.pipeline import COLUMNS, blank_record
    from bench.report import cell_fits

    if not isinstance(rec, dict) or list(rec) != list(COLUMNS):
        raise ValueError("the record's columns are not the suite's")
    for col, blank in blank_record("", "").items():
        if not cell_fits(blank, rec[col]):
            raise ValueError(f"column {col!r} holds {rec[col]!r}")


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
        self._plants: dict[str, Any] = {}
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
        """Seeded states (n, 2 PROBE_POINTS + 2): directions x scales inside the constants' radius (without one, 0.01
        to 10), directions x scales from 1 out to the samplers' reach (:func:`bench.constants.sampled_range`), x0,
        x_hat0."""
        radii = [r for c in (plant.bounds, plant.claimed, plant.channels)
                 if (r := getattr(c, "radius", None)) is not None and np.isfinite(r) and r > 0]
        inner = (np.geomspace(0.01, 10.0, _PROBE_SCALES) if not radii
                 else min(radii) * np.linspace(0.05, 0.95, _PROBE_SCALES))
        return np.concatenate([_ball(plant.n, inner, 0), _ball(plant.n, _reach_scales(sampled_range(plant)), 1),
                               np.asarray(plant.x0, dtype=float)[:, None],
                               np.asarray(plant.x_hat0, dtype=float)[:, None]], axis=1)

    @classmethod
    def _probe(cls, plant) -> str:
        """Hash of what the plant's callables compute out to the samplers' reach (:func:`_fingerprint`)."""
        return _fingerprint(plant, cls._probe_points(plant), _narrow_radii(plant, sampled_range(plant)))

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
        """The key of one pair (see the module docstring); None when it cannot be computed. The cache keeps ``plant``
        for the pair's digest (:meth:`store_pair`, :meth:`load_pair`)."""
        opts = {f.name: getattr(options, f.name) for f in dataclasses.fields(options) if f.name not in _NOT_RESULTS}
        opts["sim"] = {k: v for k, v in dataclasses.asdict(options.sim).items() if k not in _NOT_RESULTS}
        key = self._build_key(f"{plant_id} x {design_id}", "pair", plant, plant_id, design=(design, design_id),
                              options=_encode(opts, {}, set()))
        if key:
            self._plants[key] = plant
        return key

    def constants_key(self, plant, plant_id: str, options) -> str | None:
        """The key of one plant's constants; None when it cannot be computed."""
        return self._build_key(f"the constants of {plant_id}", "constants", plant, plant_id, seed=options.seed,
                               n_samples=options.n_samples)

    def _store(self, folder: str, key: str | None, obj, **extra) -> bool:
        """Write ``obj`` (and the JSON values ``extra`` beside it) as the entry ``folder/<key>.npz``; False (noted) when
        it cannot be stored."""
        if not key or not self._writable:
            return False
        path = self.root / folder / f"{key}.npz"
        try:
            arrays: dict[str, np.ndarray] = {}
            meta = json.dumps({"format": CACHE_FORMAT, "value": _encode(obj, arrays), **extra})
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

    def _load(self, folder: str, key: str | None, expected: type,
              check: Callable[[Any], None] | None = None) -> tuple[Any, dict] | None:
        """The object of the entry ``folder/<key>.npz`` and its JSON document, or None (a damaged entry noted by its
        path)."""
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
            return obj, doc
        except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run
            self.errors.append(f"damaged cache entry {path} ignored (recomputed): {type(exc).__name__}: {exc}")
            return None

    def store_pair(self, key: str | None, outcome) -> bool:
        """Store a finished pair (not its plant) with its reach and digest (module docstring); False when not cacheable
        (error, timeout, no key, a plant whose digest cannot be computed) or not written."""
        if outcome.record.get("status") in _TRANSIENT or key not in self._plants:
            return False
        try:
            checked = _pair_digest(self._plants[key], outcome)
        except Exception as exc:  # noqa: BLE001 - a cache problem never fails a run: not stored
            self.errors.append(f"cannot compute the digest of the pair {key}: {type(exc).__name__}: {exc}")
            return False
        return self._store("pairs", key, dataclasses.replace(outcome, plant=None), checked=checked)

    def load_pair(self, key: str | None):
        """The cached :class:`bench.pipeline.PairOutcome` (without its plant), or None; counts hits/misses.

        An entry whose digest, recomputed with the plant the key was computed from out to the entry's reach, differs
        (f changed where only this pair's checks looked) is a miss; so is an entry without a digest.
        """
        from bench.pipeline import PairOutcome

        found = self._load("pairs", key, PairOutcome, lambda o: _check_record(o.record))
        out = found[0] if found is not None and self._same_checks(key, *found) else None
        self.hits += out is not None
        self.misses += out is None
        return out

    def _same_checks(self, key: str, outcome, doc: dict) -> bool:
        """True when the entry's digest is what the plant of ``key`` computes now out to the entry's reach (True for a
        key this cache did not compute: no plant to compare with)."""
        plant = self._plants.get(key)
        if plant is None:
            return True
        try:
            return doc.get("checked") == _pair_digest(plant, outcome)
        except Exception:  # noqa: BLE001 - a digest that cannot be computed: a miss
            return False

    def store_constants(self, key: str | None, report) -> bool:
        """Store a plant's :class:`bench.constants.ConstantsReport`; False when not written (or no key)."""
        return self._store("constants", key, report)

    def load_constants(self, key: str | None):
        """The cached :class:`bench.constants.ConstantsReport`, or None."""
        from bench.constants import ConstantsReport

        found = self._load("constants", key, ConstantsReport)
        return None if found is None else found[0]
