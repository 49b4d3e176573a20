"""On-disk cache of finished pairs and plant constants, so that an interrupted run resumes.

``python -m bench run`` stores every finished pair (and every plant's constants) in
``.bench-cache/`` next to the report folder as soon as it finishes; a re-run takes what it
finds there instead of recomputing it, and ``--no-cache`` ignores the cache (neither reads nor
writes it). Delete the folder to reclaim the space.

Keys
----
An entry is found under the SHA-256 of everything its result depends on; a change to any of
them is a miss:

- the plant's content: id, A, B, C, x0, x_hat0 (exact bytes), t_final, params, family, the
  claimed and analytic constants, whether it has a Jacobian, the values of f at three fixed
  points (so a change hidden in a closure is seen), and the **source** of the module that
  registered it and of the modules defining its f and Jacobian;
- the design's content: id, every hyperparameter (the design object's dataclass fields,
  recursively through a pairing's parts), and the source of the modules defining it;
- the run options that change results: seed, n_samples, use_claimed, t_final, noise,
  noise_dt and the simulation settings (not ``timeout``, ``fail_fast``, ``jobs``: results do
  not depend on them);
- the versions of Python and of the packages (:func:`bench.report.package_versions`);
- the source of the shared code: the harness and everything it imports from ``bench``,
  ``designs`` and ``plants`` (except rendering and command-line modules: ``bench.report``,
  ``bench.cli``, ``bench.perf``).

"Source of a module" is closed under imports: every project module a hashed module imports
(at top level or inside a function, found by parsing its source) is hashed too, so editing
``designs/thm1.py`` also invalidates Corollary 1, which imports helpers from it.

Entries
-------
``pairs/<key>.npz``: the record, the design result and the trajectory, as one JSON document
plus numpy arrays (``allow_pickle=False``: no pickled objects); ``constants/<key>.json``: a
:class:`bench.constants.ConstantsReport`. Each file is written to a temporary name and moved
into place with ``os.replace``, so an interrupted write leaves no partial entry; an unreadable
entry is a miss. Rows with status ``error`` or ``timeout`` are not stored (they may be
transient: a worker that died, a loaded machine).
"""

from __future__ import annotations

import ast
import dataclasses
import hashlib
import importlib
import importlib.util
import json
import os
import warnings
import sys
import tempfile
from pathlib import Path
from typing import IO, Any, Callable

import numpy as np

__all__ = ["CACHE_FORMAT", "Cache", "default_cache_dir"]

#: Bumped when the layout or the meaning of an entry changes.
CACHE_FORMAT = 1

#: Packages whose modules are hashed by source (plus plugin modules).
_PROJECT = ("bench", "designs", "plants")

#: Statuses that are never stored.
_TRANSIENT = ("error", "timeout")

#: Rendering and command-line modules: they do not change a pair's result, so editing them
#: does not invalidate the cache (their imports are not followed either).
_NOT_RESULTS = frozenset({"bench.report", "bench.cli", "bench.perf", "bench.__main__"})


def default_cache_dir(out_dir: str | os.PathLike) -> Path:
    """``.bench-cache`` next to the report folder ``out_dir`` (its sibling)."""
    return Path(os.path.abspath(out_dir)).parent / ".bench-cache"


def _is_project(name: str) -> bool:
    return name.split(".")[0] in _PROJECT or name.startswith("oslbench_plugin_")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


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
        Problems met (an unwritable folder, an unreadable entry); a cache problem never fails
        a run, it only costs a recomputation.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.hits = self.misses = self.constants_hits = self.constants_misses = self.stored = 0
        self.errors: list[str] = []
        self._sources: dict[str, str] = {}
        self._deps: dict[str, set[str]] = {}
        self._fixed: dict[str, Any] | None = None
        self._writable = True

    # -- fingerprints ------------------------------------------------------------------------
    def _source_hash(self, name: str) -> str:
        if name not in self._sources:
            mod = sys.modules.get(name)
            path = getattr(mod, "__file__", None)
            if path is None:
                try:
                    spec = importlib.util.find_spec(name)
                    path = spec.origin if spec is not None else None
                except (ImportError, ValueError):
                    path = None
            try:
                self._sources[name] = _sha(Path(path).read_bytes()) if path else "no source"
            except OSError:
                self._sources[name] = "unreadable source"
        return self._sources[name]

    def _imports(self, name: str) -> set[str]:
        """Project modules that module ``name`` imports anywhere in its source."""
        if name in self._deps:
            return self._deps[name]
        deps: set[str] = set()
        self._deps[name] = deps
        mod = sys.modules.get(name)
        path = getattr(mod, "__file__", None)
        try:
            tree = ast.parse(Path(path).read_bytes()) if path else None
        except (OSError, SyntaxError, ValueError):
            tree = None
        for node in ast.walk(tree) if tree is not None else ():
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if _is_project(a.name))
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and _is_project(node.module):
                deps.add(node.module)
                for a in node.names:
                    sub = f"{node.module}.{a.name}"
                    if sub in sys.modules or self._is_module(sub):
                        deps.add(sub)
        return deps

    @staticmethod
    def _is_module(name: str) -> bool:
        try:
            return importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):
            return False

    def _code(self, roots: set[str]) -> dict[str, str]:
        """Source hashes of ``roots`` and every project module they import, transitively."""
        seen: set[str] = set()
        todo = [r for r in roots if r and (_is_project(r) or r in sys.modules)]
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

    def _fixed_parts(self) -> dict[str, Any]:
        if self._fixed is None:
            from bench.report import package_versions

            self._fixed = {"format": CACHE_FORMAT, "versions": package_versions(),
                           "code": self._code({"bench.harness", "bench.estimators", "bench.cache"})}
        return self._fixed

    def plant_fingerprint(self, plant, plant_id: str) -> dict[str, Any]:
        """The content of a plant (data, constants, and the source of its modules)."""
        from bench.registry import PLANTS

        modules: set[str] = set()
        data = {
            "id": plant_id,
            **{k: _canon(np.asarray(getattr(plant, k)), modules) for k in ("A", "B", "C", "x0", "x_hat0")},
            "t_final": _canon(plant.t_final, modules),
            "params": _canon(dict(plant.params), modules),
            "family": plant.family,
            "claimed": _canon(plant.claimed, modules),
            "bounds": _canon(plant.bounds, modules),
            "jacobian": plant.jacobian is not None,
            "f": _canon(plant.f, modules),
            "f_probe": self._probe(plant),
        }
        if plant.jacobian is not None:
            _canon(plant.jacobian, modules)
        try:
            modules.add(PLANTS[plant_id].module)
        except KeyError:
            pass
        data["code"] = self._code(modules)
        return data

    @staticmethod
    def _probe(plant) -> str:
        """Hash of f at three fixed points: catches a change of f that hides in a closure."""
        n = plant.n
        pts = np.stack([np.asarray(plant.x0, dtype=float) + 0.5, np.linspace(-1.0, 1.0, n),
                        np.cos(np.arange(1.0, n + 1.0))], axis=1)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return _sha(np.ascontiguousarray(np.asarray(plant.f(pts), dtype=float)).tobytes())
        except Exception as exc:  # noqa: BLE001 - the harness reports a broken f; the key only notes it
            return f"probe failed: {type(exc).__name__}"

    def design_fingerprint(self, design, design_id: str) -> dict[str, Any]:
        """The content of a design (hyperparameters, recursively, and the source of its modules)."""
        from bench.registry import DESIGNS

        modules: set[str] = set()
        data = {"id": design_id, "design": _canon(design, modules)}
        try:
            modules.add(DESIGNS[design_id].module)
        except KeyError:
            pass
        data["code"] = self._code(modules)
        return data

    @staticmethod
    def _options(options) -> dict[str, Any]:
        sim = {f.name: _canon(getattr(options.sim, f.name), set()) for f in dataclasses.fields(options.sim)
               if f.name != "max_wall_s"}
        return {"seed": options.seed, "n_samples": options.n_samples, "use_claimed": options.use_claimed,
                "t_final": _canon(options.t_final, set()), "noise": _canon(options.noise, set()),
                "noise_dt": _canon(options.noise_dt, set()), "sim": sim}

    def _key(self, doc: dict) -> str:
        return _sha(json.dumps(doc, sort_keys=True).encode())

    def pair_key(self, plant, plant_id: str, design, design_id: str, options) -> str:
        """The key of one pair (see the module docstring)."""
        return self._key({"kind": "pair", **self._fixed_parts(), "plant": self.plant_fingerprint(plant, plant_id),
                          "design": self.design_fingerprint(design, design_id), "options": self._options(options)})

    def constants_key(self, plant, plant_id: str, options) -> str:
        """The key of one plant's constants (plant content, seed, n_samples, code, versions)."""
        return self._key({"kind": "constants", **self._fixed_parts(),
                          "plant": self.plant_fingerprint(plant, plant_id),
                          "seed": options.seed, "n_samples": options.n_samples})

    # -- storage ------------------------------------------------------------------------------
    def _write(self, path: Path, write: Callable[[IO[bytes]], None]) -> bool:
        if not self._writable:
            return False
        try:
            _atomic_write(path, write)
        except OSError as exc:  # an unwritable folder, a full disk: run on without the cache
            self._writable = False
            self.errors.append(f"cannot write the cache {self.root}: {exc}")
            return False
        self.stored += 1
        return True

    def store_pair(self, key: str, outcome) -> bool:
        """Store a finished pair; False when it is not cacheable (error, timeout) or not written."""
        rec = outcome.record
        if rec.get("status") in _TRANSIENT:
            return False
        arrays: dict[str, np.ndarray] = {}
        meta: dict[str, Any] = {"format": CACHE_FORMAT, "record": {k: _plain(v) for k, v in rec.items()},
                                "result": None, "trajectory": None}
        res = outcome.result
        if res is not None:
            d = {f.name: getattr(res, f.name) for f in dataclasses.fields(res) if f.name not in ("K", "F", "estimator")}
            d["min_eig"] = {k: _plain(v) for k, v in d["min_eig"].items()}
            d["params"] = {k: _plain(v) for k, v in d["params"].items()}
            est = res.estimator
            if est is not None:
                if not dataclasses.is_dataclass(est):
                    return False  # cannot be rebuilt without pickling
                d["estimator"] = {"type": [type(est).__module__, type(est).__qualname__],
                                  "fields": {k: _plain(v) for k, v in dataclasses.asdict(est).items()}}
            meta["result"] = d
            for name in ("K", "F"):
                if getattr(res, name) is not None:
                    arrays[name] = np.asarray(getattr(res, name), dtype=float)
        tr = outcome.trajectory
        if tr is not None:
            meta["trajectory"] = {"status": tr.status, "message": tr.message, "wall_s": tr.wall_s, "nfev": int(tr.nfev)}
            arrays.update(t=tr.t, x=tr.x, x_hat=tr.x_hat, u=tr.u)
        try:
            text = json.dumps(meta, default=repr)
        except (TypeError, ValueError):
            return False
        arrays["meta"] = np.array(text)
        return self._write(self.root / "pairs" / f"{key}.npz", lambda fh: np.savez_compressed(fh, **arrays))

    def load_pair(self, key: str):
        """The cached :class:`bench.harness.PairOutcome` (without its plant), or None; counts hits/misses."""
        path = self.root / "pairs" / f"{key}.npz"
        out = None
        if path.is_file():
            try:
                out = self._read_pair(path)
            except Exception as exc:  # noqa: BLE001 - a damaged entry is a miss
                self.errors.append(f"unreadable cache entry {path.name}: {type(exc).__name__}: {exc}")
        if out is None:
            self.misses += 1
        else:
            self.hits += 1
        return out

    @staticmethod
    def _read_pair(path: Path):
        from bench.harness import COLUMNS, PairOutcome
        from bench.simulate import Trajectory
        from designs._core import DesignResult

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
            result = DesignResult(**d, K=arrays.get("K"), F=arrays.get("F"), estimator=est)
        traj = None
        if meta["trajectory"] is not None:
            tm = meta["trajectory"]
            traj = Trajectory(arrays["t"], arrays["x"], arrays["x_hat"], arrays["u"], tm["status"], tm["message"],
                              tm["wall_s"], tm["nfev"])
        return PairOutcome(rec, result=result, trajectory=traj)

    def store_constants(self, key: str, report) -> bool:
        """Store a plant's :class:`bench.constants.ConstantsReport`."""
        doc = {
            "format": CACHE_FORMAT,
            **{k: (None if getattr(report, k) is None else getattr(report, k).as_dict())
               for k in ("claimed", "analytic", "sampled", "valid")},
            "source": report.source,
            "violations": [{"name": v.name, "claimed": _plain(v.claimed), "sampled": _plain(v.sampled),
                            "x1": [_plain(a) for a in v.x1], "x2": [_plain(a) for a in v.x2]}
                           for v in report.violations],
            "seed": report.seed,
            "n_samples": report.n_samples,
        }
        try:
            text = json.dumps(doc).encode()
        except (TypeError, ValueError):
            return False
        return self._write(self.root / "constants" / f"{key}.json", lambda fh: fh.write(text))

    def load_constants(self, key: str):
        """The cached :class:`bench.constants.ConstantsReport`, or None."""
        from bench.constants import ConstantsReport, Violation
        from plants._core import Constants

        path = self.root / "constants" / f"{key}.json"
        rep = None
        if path.is_file():
            try:
                doc = json.loads(path.read_text(encoding="utf-8"))
                if doc.get("format") == CACHE_FORMAT:
                    cs = {k: None if doc[k] is None else Constants(**doc[k])
                          for k in ("claimed", "analytic", "sampled", "valid")}
                    viol = [Violation(v["name"], v["claimed"], v["sampled"], tuple(v["x1"]), tuple(v["x2"]))
                            for v in doc["violations"]]
                    rep = ConstantsReport(**cs, source=doc["source"], violations=viol, seed=doc["seed"],
                                          n_samples=doc["n_samples"])
            except Exception as exc:  # noqa: BLE001 - a damaged entry is a miss
                self.errors.append(f"unreadable cache entry {path.name}: {type(exc).__name__}: {exc}")
        if rep is None:
            self.constants_misses += 1
        else:
            self.constants_hits += 1
        return rep
