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


def test_parallel_keeps_the_order_of_its_calls_and_raises_their_errors():
    import threading

    import pytest

    from bench._env import parallel

    seen = set()

    def call(i):
        seen.add(threading.get_ident())
        return i * i

    assert parallel([lambda i=i: call(i) for i in range(5)], n=10_000) == [0, 1, 4, 9, 16]
    assert parallel([lambda i=i: call(i) for i in range(3)], n=2) == [0, 1, 4]  # small: serial, same answer

    def boom():
        raise ValueError("the third call")

    with pytest.raises(ValueError, match="the third call"):
        parallel([lambda: 1, lambda: 2, boom], n=10_000)
