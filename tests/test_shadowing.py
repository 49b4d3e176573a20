"""A local plants.py, designs.py (or such a folder) or bench.py in the working folder does not break the command
(issue 35): ``python -m bench`` leaves the working folder off the module path, an import elsewhere names the file."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _python(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("local", ["plants.py", "designs.py", "plants/__init__.py", "designs/__init__.py"])
def test_python_m_bench_ignores_a_local_module(tmp_path, local):
    path = tmp_path / local
    path.parent.mkdir(exist_ok=True)
    path.write_text("raise RuntimeError('the local module was imported')\n", encoding="utf-8")
    out = _python(["-m", "bench", "list"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert "flexible_link" in out.stdout and "thm1" in out.stdout


def test_an_import_elsewhere_names_the_shadowing_file(tmp_path):
    (tmp_path / "designs.py").write_text("X = 1\n", encoding="utf-8")
    out = _python(["-c", "import bench"], tmp_path)
    assert out.returncode == 1
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: a local file ") and str(tmp_path / "designs.py") in last
    assert "shadows the oslbench package 'designs'" in last and "rename it" in last


def test_the_installed_command_ignores_a_local_bench_py(tmp_path):
    """``python -m bench`` runs a local bench.py (Python's rule, before any of this package runs); the ``oslbench``
    script does not look in the working folder at all. Its stand-in here: a script in another folder."""
    (tmp_path / "bench.py").write_text("raise SystemExit('the local bench.py ran')\n", encoding="utf-8")
    (tmp_path / "plants.py").write_text("X = 1\n", encoding="utf-8")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "oslbench"
    script.write_text("import sys\nfrom bench.cli import main\nsys.exit(main())\n", encoding="utf-8")
    out = _python([str(script), "--version"], tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("oslbench ") and str(ROOT) in out.stdout
