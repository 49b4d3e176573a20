"""Code measures of bench/, designs/ and plants/: lines, functions over 60 lines, modules defining exception classes, names in __all__ lists, imports of private names (`python benchmarks/code_counts.py [-v]`)."""
import ast, pathlib, sys, re
root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".")
files = [p for d in ("bench", "designs", "plants") for p in (root / d).rglob("*.py")]
lines = sum(len(p.read_text().splitlines()) for p in files)
long, exc_mods, alln, priv = [], set(), 0, []
for p in files:
    t = ast.parse(p.read_text())
    for n in ast.walk(t):
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.end_lineno - n.lineno + 1 > 60:
            long.append(f"{p.relative_to(root)}:{n.name}:{n.end_lineno - n.lineno + 1}")
        if isinstance(n, ast.ClassDef) and any(
            (isinstance(b, ast.Name) and (b.id.endswith(("Error", "Exception")) or b.id in ("Exception", "ValueError", "RuntimeError", "TypeError")))
            or (isinstance(b, ast.Attribute) and b.attr.endswith("Error")) for b in n.bases):
            exc_mods.add(str(p.relative_to(root)))
        if isinstance(n, ast.Assign) and any(isinstance(tg, ast.Name) and tg.id == "__all__" for tg in n.targets):
            try: alln += len(ast.literal_eval(n.value))
            except Exception: pass
        if isinstance(n, ast.ImportFrom) and n.module and n.level == 0 and n.module.split(".")[0] in ("bench", "designs", "plants"):
            for a in n.names:
                if a.name.startswith("_") and not a.name.startswith("__"):
                    priv.append(f"{p.relative_to(root)}: from {n.module} import {a.name}")
print(f"lines {lines}; functions>60 {len(long)}; exception modules {len(exc_mods)}; __all__ names {alln}; private imports {len(priv)}")
if "-v" in sys.argv:
    print("\n".join(long)); print(sorted(exc_mods)); print("\n".join(priv))
