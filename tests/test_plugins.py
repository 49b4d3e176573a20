"""Users' own plants through --plugin: the README example works as printed, errors exit 2
naming the file, and a failed plugin leaves the registries as they were."""

import csv
from pathlib import Path

import pytest

from bench.cli import main
from bench.plugins import PluginError, load_plugin
from bench.registry import DESIGNS, PLANTS
from tests._plugin_helpers import clean_registries  # noqa: F401 - autouse: registries restored after each test

ROOT = Path(__file__).resolve().parents[1]


def readme_example() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Your own plant"):]
    code = section[section.index("```python\n") + len("```python\n"):]
    return code[: code.index("```")]


def test_readme_example_is_the_example_file_and_short():
    code = readme_example()
    assert code == (ROOT / "examples" / "my_plants.py").read_text(encoding="utf-8")
    assert 10 <= len(code.strip().splitlines()) <= 20


def test_readme_example_runs(tmp_path, capsys):
    plugin = tmp_path / "my_plants.py"
    plugin.write_text(readme_example(), encoding="utf-8")
    assert main(["list", "--plugin", str(plugin)]) == 0
    assert "my_plant" in capsys.readouterr().out
    PLANTS.unregister("my_plant")
    out = tmp_path / "rep"
    code = main(["run", "--plugin", str(plugin), "--plant", "my_plant", "--design", "cor1", "--out", str(out),
                 "--no-figures", "-q"])
    assert code == 0
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert [(r["plant"], r["design"]) for r in rows] == [("my_plant", "cor1")]
    assert rows[0]["status"] == "feasible"  # alpha = 0.5 on a stable oscillator: an easy case
    assert "my_plant" in (out / "REPORT.md").read_text()


BAD = {
    "syntax": ("def f(:\n", "syntax error (line 1)"),
    "import": ("import numpy\nimport no_such_module_xyz\n", "line 2): ModuleNotFoundError"),
    "nothing": ("X = 1\n", "registers no plant or design"),
    "duplicate": (
        "from bench.registry import register_plant\n"
        "@register_plant('flexible_link')\n"
        "def f():\n    pass\n",
        "duplicate plant id 'flexible_link'",
    ),
    "validation": (
        "import numpy as np\n"
        "from bench.registry import register_plant\n"
        "from plants import Plant\n"
        "@register_plant('bad_f')\n"
        "def bad_f():\n"
        "    return Plant(id='bad_f', A=np.eye(2), B=np.ones((2, 1)), C=np.ones((1, 2)),\n"
        "                 f=lambda x: np.ones_like(x), x0=[1, 0], x_hat0=[0, 0])\n",
        "plant 'bad_f' cannot be built with its defaults (line 6): PlantError: f: f(0) must be 0",
    ),
    "raises": (
        "from bench.registry import register_plant\n"
        "@register_plant('boom')\n"
        "def boom():\n    return 1 / 0\n",
        "(line 4): ZeroDivisionError",
    ),
    "id_mismatch": (
        "from bench.registry import register_plant\n"
        "from plants.pendulum import pendulum\n"
        "register_plant('other_name')(pendulum)\n",
        "has id 'pendulum_v1'",
    ),
    "exits": ("import sys\nsys.exit(3)\n", "called sys.exit(3)"),
}


@pytest.mark.parametrize("kind", sorted(BAD))
@pytest.mark.parametrize("command", ["list", "run"])
def test_bad_plugin_exits_2_naming_the_file(tmp_path, capsys, kind, command):
    src, words = BAD[kind]
    plugin = tmp_path / f"plug_{kind}.py"
    plugin.write_text(src, encoding="utf-8")
    before = (PLANTS.ids(), DESIGNS.ids())
    argv = [command, "--plugin", str(plugin)] + (["--out", str(tmp_path / "r")] if command == "run" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(plugin) in err and words in err, err
    assert "Traceback" not in err
    assert (PLANTS.ids(), DESIGNS.ids()) == before  # nothing left registered
    assert not (tmp_path / "r").exists()


def test_missing_plugin_file(tmp_path, capsys):
    missing = tmp_path / "nope.py"
    assert main(["run", "--plugin", str(missing), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "no such file" in err
    assert main(["list", "--plugin", str(tmp_path)]) == 2
    assert "not a file" in capsys.readouterr().err


def test_load_plugin_api_and_double_load(tmp_path):
    helper = tmp_path / "my_helper.py"
    helper.write_text("C_VALUE = 0.25\n", encoding="utf-8")
    plugin = tmp_path / "uses_helper.py"
    plugin.write_text(readme_example().replace('"my_plant"', '"helper_plant"').replace(
        "c: float = 0.5", "c: float = C_VALUE").replace("import numpy as np\n",
                                                       "import numpy as np\nfrom my_helper import C_VALUE\n"),
                      encoding="utf-8")
    assert load_plugin(plugin) == ["helper_plant"]  # a helper next to the plugin imports
    assert PLANTS.create("helper_plant").params == {"c": 0.25}
    with pytest.raises(PluginError, match="duplicate plant id 'helper_plant'") as info:
        load_plugin(plugin)
    assert str(plugin) in str(info.value)
    assert "helper_plant" in PLANTS.ids()  # the first load is untouched


def test_two_plugins_and_a_design(tmp_path, capsys):
    a = tmp_path / "a.py"
    a.write_text(readme_example(), encoding="utf-8")
    b = tmp_path / "b.py"
    b.write_text(
        "from dataclasses import dataclass\n"
        "from bench.registry import register_design\n"
        "from designs.paper_gains import PaperGains\n"
        "@register_design('my_design')\n"
        "@dataclass(frozen=True, kw_only=True)\n"
        "class Mine(PaperGains):\n"
        "    '''My design.'''\n",
        encoding="utf-8",
    )
    assert main(["list", "--plugin", str(a), "--plugin", str(b)]) == 0
    out = capsys.readouterr().out
    assert "my_plant" in out and "my_design" in out
