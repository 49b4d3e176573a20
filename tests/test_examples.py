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
    # python-control's own simulation of the nonlinear closed loop (not the suite's simulator)
    # from x0 = (1, 0): after 10 s the state is far below its start
    final = float(re.search(r"python-control: \|\|x\(10\)\|\| = (\S+)", done.stdout).group(1))
    assert final < 1e-2
