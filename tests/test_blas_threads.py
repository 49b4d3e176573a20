"""bench limits BLAS to one thread whatever was imported first (bench/_env.py)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CODE = """
import json
import numpy  # before bench: its BLAS is loaded with the machine's default thread count
import bench
from threadpoolctl import threadpool_info
print(json.dumps([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]))
"""


def _blas_threads(env_extra: dict) -> list[int]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(env_extra, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", _CODE], env=env, capture_output=True, text=True, timeout=120,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_numpy_imported_first_still_gets_one_blas_thread():
    threads = _blas_threads({})
    assert threads and all(t == 1 for t in threads)


def test_a_users_thread_setting_is_kept():
    # OPENBLAS_NUM_THREADS=2 set by the user: numpy starts with 2 threads and bench keeps them
    assert all(t == 2 for t in _blas_threads({"OPENBLAS_NUM_THREADS": "2"}))
