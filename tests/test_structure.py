"""Module structure (issue 35): the two command lines do not import each other, and no module imports another
package's private module (``plants._core`` from bench, ``bench._env`` from designs)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "plants", "designs")


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports (absolute names; ``from a import b`` gives ``a`` and ``a.b``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    pkg = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            out.add(base)
            out |= {f"{base}.{a.name}" for a in node.names}
    return out


def _modules():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield path


def test_the_command_lines_do_not_import_each_other():
    run_cli, study_cli = _imports(ROOT / "bench" / "cli.py"), _imports(ROOT / "bench" / "studies" / "cli.py")
    assert "bench.cli" not in study_cli and not any(m.startswith("bench.cli.") for m in study_cli)
    assert "bench.studies.cli" in run_cli  # one direction: run's parser adds the study subcommand
    assert "bench.cli_common" in run_cli and "bench.cli_common" in study_cli


@pytest.mark.parametrize("path", list(_modules()), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_module_of_another_package(path):
    own = path.relative_to(ROOT).parts[0]
    bad = sorted(m for m in _imports(path)
                 if m.split(".")[0] in PACKAGES and m.split(".")[0] != own
                 and any(part.startswith("_") for part in m.split(".")[1:2]))
    assert not bad, f"{path.relative_to(ROOT)} imports another package's private module: {bad}"


def test_the_public_homes_exist():
    from bench.threads import cores, parallel
    from plants import jacobian_mismatch

    assert cores() >= 1 and parallel([lambda: 1, lambda: 2]) == [1, 2] and callable(jacobian_mismatch)
