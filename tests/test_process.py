from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = """
import json
from services.lib.process import prepare_process
prepare_process()
import services.defects.measure  # loads SciPy's own OpenBLAS, after the set-up
from threadpoolctl import threadpool_info
print(json.dumps({i["filepath"]: i["num_threads"] for i in threadpool_info()}))
"""


def test_a_blas_loaded_after_the_set_up_runs_one_thread_too():
    # SciPy's OpenBLAS (numba's np.dot calls it) is loaded by the first scipy.ndimage
    # import; with a thread per core, its idle thread spins on the measurement's cores.
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    probe = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True
    )
    threads = json.loads(probe.stdout)
    assert any("scipy_openblas-" in path for path in threads), threads  # SciPy's own
    assert set(threads.values()) == {1}, threads
