"""teleop.util.numba_cache.load_cached_kernels: a fresh process loads, before any call, the
signatures an earlier process cached for a kernel, and a call afterwards loads nothing more (the
two-process warm-up's last step: kernels its twin never reaches, such as one called only in
contact, no longer load on the first touch, mid-run)."""

import subprocess
import sys

CALL = """
import numpy as np
from teleop.contact import kernels as k
k.block_damping(np.zeros(3), np.eye(3), np.zeros(3), np.array([0, 0, 0, 0, 0, 1.0, 1, 1, 1]),
                np.array([1.0, 1.0, 0.0, 1e-3, 1.0]))
"""

PRELOAD = """
import numpy as np
from teleop.contact import kernels as k
from teleop.util.numba_cache import load_cached_kernels
assert len(k.block_damping.overloads) == 0, "loaded before it was asked"
n = load_cached_kernels()
before = set(k.block_damping.overloads)
assert n >= 1 and before, (n, before)
k.block_damping(np.zeros(3), np.eye(3), np.zeros(3), np.array([0, 0, 0, 0, 0, 1.0, 1, 1, 1]),
                np.array([1.0, 1.0, 0.0, 1e-3, 1.0]))
assert set(k.block_damping.overloads) == before, "the call loaded another signature"
assert load_cached_kernels() == 0  # all loaded already
print("ok", n)
"""


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)


def test_a_fresh_process_loads_what_an_earlier_one_cached_before_any_call():
    first = _python(CALL)  # caches the signature (or finds it cached)
    assert first.returncode == 0, first.stderr[-2000:]
    second = _python(PRELOAD)
    assert second.returncode == 0, second.stderr[-2000:]
    assert second.stdout.startswith("ok")
