"""Run by a user who cannot write to the package's folder nor to $HOME: the kernels still import
(numba's cache goes to a writable folder, teleop.util.numba_cache), never a failure at import."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import teleop
from teleop.util import numba_cache

PKG = Path(teleop.__file__).resolve().parent


def _can_remount() -> bool:
    if shutil.which("unshare") is None:
        return False
    r = subprocess.run(["unshare", "-m", "true"], capture_output=True)
    return r.returncode == 0


@pytest.mark.skipif(not _can_remount(), reason="needs unshare -m (root in a container) to mount read-only")
def test_kernels_import_from_a_read_only_package_with_no_home(tmp_path):
    copy = tmp_path / "ro"
    shutil.copytree(PKG, copy / "teleop", symlinks=False, ignore=shutil.ignore_patterns("__pycache__"))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    code = "import teleop.dynamics.kernels.rows, os; print(os.environ.get('NUMBA_CACHE_DIR'))"
    script = (f"mount --bind {copy} {copy} && mount -o remount,bind,ro {copy} && "
              f"{sys.executable} -c \"{code}\"")
    env = {**os.environ, "HOME": "/proc/no-home", "XDG_CACHE_HOME": "", "TMPDIR": str(tmp), "PYTHONPATH": str(copy)}
    env.pop("NUMBA_CACHE_DIR", None)
    r = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, env=env, timeout=120,
                       cwd=tmp)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().startswith(str(tmp)), r.stdout


def test_the_users_own_choice_is_kept(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert numba_cache.choose_cache_dir() is None


def test_a_read_only_package_picks_the_first_writable_candidate(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(numba_cache, "candidates", lambda: [Path("/proc/no/such"), tmp_path / "c"])
    assert numba_cache.choose_cache_dir(Path("/proc/not-writable")) == tmp_path / "c"
    monkeypatch.setattr(numba_cache, "candidates", lambda: [Path("/proc/no/such")])
    assert numba_cache.choose_cache_dir(Path("/proc/not-writable")) == Path("")  # caching off
