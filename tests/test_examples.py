"""The examples run as written: the notebook-style tour (examples/notebook_tour.py)."""

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_notebook_tour_runs_and_its_loop_converges_in_python_control(tmp_path):
    out = tmp_path / "tour.png"
    env = {**os.environ, "MPLBACKEND": "Agg", "OSLBENCH_TOUR_OUT": str(out)}
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "notebook_tour.py")], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert out.is_file() and out.stat().st_size > 0
    # the table has the three designs the tour asked for
    for did in ("thm1", "structured", "lqr+lqe"):
        assert re.search(rf"^\s*{re.escape(did)}\s", done.stdout, re.M), did
    # the sweep by objects: one row per object, named by its changed setting; a looser bound on the gains
    # certifies at least the rate of a tighter one (its feasible set contains the tighter one's)
    rates = [float(re.search(rf"^\s*structured\[max_gain={g}\]\s+feasible\s+True\s+(\S+)", done.stdout, re.M)
                   .group(1)) for g in ("2.0", "5.0")]
    assert 0 < rates[0] <= rates[1]
    # python-control's own simulation of the nonlinear closed loop (not the suite's simulator)
    # from x0 = (1, 0): after 10 s the state is far below its start
    final = float(re.search(r"python-control: \|\|x\(10\)\|\| = (\S+)", done.stdout).group(1))
    assert final < 1e-2


# -- examples/my_design.py: a design of one's own gets every column a built-in design gets ------------------
#: Columns that only an SDP design fills (an LMI's size, margin, solver); a formula design leaves them blank.
_SDP_ONLY = {"lmi_margin", "lmi_size", "solver", "solver_status", "compile_s", "solve_s"}
#: Columns filled only when some level certifies (the rate, the level, the scope of the certificate).
_IF_CERTIFIED = {"cert_level", "decay_rate", "cert_scope", "level_x0", "level_set", "cert_radius", "decay_paper",
                 "decay_full", "decay_structured", "cert_margin", "rate_ceiling", "rate_ratio", "ceiling_how",
                 "cert_horizon_s"}


def _filled(row) -> set[str]:
    import pandas as pd

    return {k for k, v in row.items() if not (v is None or (not isinstance(v, str) and pd.isna(v)) or v == "")}


def _check_like_builtin(mine, builtin) -> None:
    """``mine`` (the pole-placement row) has the ladder, convergence and timing columns a built-in
    design of the same kind (lqr+lqe: gains from a formula) has, and its gains place the poles."""
    from bench.certify import LEVEL_STATUSES, LEVELS

    assert mine["status"] == "computed"
    for lv in LEVELS:
        assert mine[f"cert_{lv}"] in LEVEL_STATUSES, (lv, mine[f"cert_{lv}"])
    for col in ("converged", "horizon_s", "settling_x_s", "settling_e_s", "peak_u", "design_s", "cert_s", "sim_s"):
        assert col in _filled(mine), col
    assert mine["converged"] in (True, "True")
    assert _filled(builtin) - _SDP_ONLY - _IF_CERTIFIED - {"reason", "details"} <= _filled(mine)
    if mine["certified"] in (True, "True"):
        assert {"cert_level", "decay_rate", "cert_scope"} <= _filled(mine)
    # rate 2, speed 3 on the 4-state flexible link: eig(A + BF) = -2, -3, -4, -5 and eig(A - KC) = 3 times those
    assert abs(float(mine["max_re_eig_x"]) + 2.0) < 1e-6
    assert abs(float(mine["max_re_eig_e"]) + 6.0) < 1e-6


def test_my_design_runs_as_a_plugin_like_a_builtin_design(tmp_path):
    import pandas as pd

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "bench", "run", "--plugin", str(ROOT / "examples" / "my_design.py"),
                           "--plant", "flexible_link", "--design", "my_poles", "--design", "lqr+lqe",
                           "--out", str(tmp_path / "out"), "--no-figures", "--no-cache", "-q", "-j", "1"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    df = pd.read_csv(tmp_path / "out" / "results.csv").set_index("design")
    assert list(df.index) == ["my_poles", "lqr+lqe"]  # the order asked for
    _check_like_builtin(df.loc["my_poles"].to_dict(), df.loc["lqr+lqe"].to_dict())


def test_my_design_runs_through_bench_run_as_an_object():
    import importlib.util

    import bench
    from bench.registry import DESIGNS

    spec = importlib.util.spec_from_file_location("oslbench_example_my_design", ROOT / "examples" / "my_design.py")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)  # registers "my_poles"
        # named by its class's registered id and the hyperparameters that differ from the defaults (rate 2.0)
        r = bench.run(plants=["flexible_link"], designs=[mod.PolePlacement(), mod.PolePlacement(rate=1.0), "lqr+lqe"],
                      jobs=1, progress=False)
        rows = r.table.set_index("design")
        assert list(rows.index) == ["my_poles", "my_poles[rate=1.0]", "lqr+lqe"]
        _check_like_builtin(rows.loc["my_poles"].to_dict(), rows.loc["lqr+lqe"].to_dict())
        assert r.gains["flexible_link", "my_poles"]["certificate"] is not None  # the ladder ran
        assert abs(rows.loc["my_poles[rate=1.0]", "max_re_eig_x"] + 1.0) < 1e-6  # eig(A + BF) = -1, -1.5, ...
        assert "my_poles[rate=1.0]" not in DESIGNS  # not registered: the call's own
    finally:
        DESIGNS.unregister("my_poles")


def test_readme_design_example_is_the_example_file():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Your own design"):]
    code = section[section.index("```python\n") + len("```python\n"):]
    assert code[: code.index("```")] == (ROOT / "examples" / "my_design.py").read_text(encoding="utf-8")
