"""The documents a new user looks for (issue 35): the plant page generated from the registry, the licence, the
citation of the paper and of the software, and the virtual environment before README's two commands."""

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOI = "10.1177/1687814015619555"


def test_the_plant_page_is_what_the_registry_prints():
    """docs/plants.md is generated: regenerate it with `python -m bench docs-plants --out docs/plants.md`."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-m", "bench", "docs-plants"], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert (ROOT / "docs" / "plants.md").read_text(encoding="utf-8") == out.stdout


def test_the_plant_page_describes_every_plant():
    from bench.plantdoc import plants_markdown
    from bench.registry import PLANTS

    page = plants_markdown()
    for pid in PLANTS.ids():
        plant = PLANTS.create(pid)
        section = page.split(f"### `{pid}`")[1].split("\n### ")[0]
        for needle in ("A = [", "B = [", "C = [", "**f**", "constants claimed", "analytic constants", "**source**"):
            assert needle in section, (pid, needle)
        for name in plant.state_names or ():
            assert f"| {name} |" in section, (pid, name)
    assert "| x4 | omega_l / 10 [rad/s] | 2 | -1 |" in page  # flexible_link's last state, x0 and x_hat0


def test_licence_is_the_one_pyproject_declares():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert meta["license"] == "MIT" and text.startswith("MIT License")
    assert "Copyright (c) 2026 oslbench contributors" in text


def test_citation_file_cites_the_software_and_the_paper():
    yaml = pytest.importorskip("yaml")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software" and cff["license"] == meta["license"]
    assert str(cff["version"]) == meta["version"]
    for key in ("title", "authors", "message"):
        assert cff[key]
    paper = cff["references"][0]
    assert paper["doi"] == DOI and paper["type"] == "article" and paper["authors"] and paper["year"] == 2015
    assert paper["title"].startswith("Observer-based stabilization of one-sided Lipschitz systems")
    for doc in ("README.md", "docs/paper.md"):  # the same DOI where a reader looks
        assert f"https://doi.org/{DOI}" in (ROOT / doc).read_text(encoding="utf-8"), doc


def test_readme_creates_a_venv_before_its_two_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Two commands")[1].split("\n## ")[0]
    blocks = re.findall(r"```sh\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 3
    assert "python3 -m venv .venv && . .venv/bin/activate" in blocks[0]
    assert "python -m pip install . && python -m bench run" in blocks[1]
    assert 'python -m pip install ".[test]" && python -m pytest' in blocks[2]
