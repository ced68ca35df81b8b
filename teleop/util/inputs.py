"""How teleop reads a file it is handed: regular files only, with a size limit, and a run log
checked before any array of it is inflated.

* :func:`read_bytes` opens without blocking (a FIFO never hangs), refuses anything that is not a
  regular file (a directory, a FIFO, ``/dev/zero``, a socket) and anything larger than its limit,
  and turns every OS error into one :class:`~teleop.util.errors.ConfigError` naming the file.
* :func:`read_text` decodes UTF-8 (a decode error names the byte offset).
* :func:`load_run_log` reads a ``log.npz`` written by ``teleop run --out``: it checks the zip's
  members (names, count, inflated size against :data:`MAX_LOG_INFLATED_BYTES`) before reading
  one, loads with ``allow_pickle=False``, and checks every array's dtype and shape against
  :data:`LOG_SCHEMA` and the summary's JSON.
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
import zipfile
from pathlib import Path

import numpy as np

from teleop.util.errors import ConfigError, plain

#: the largest scene file, URDF or other text input read, bytes
MAX_TEXT_BYTES = 10_000_000
#: the largest run log accepted (on disk and inflated), bytes
MAX_LOG_BYTES = 4_000_000_000
MAX_LOG_INFLATED_BYTES = 4_000_000_000
MAX_LOG_MEMBERS = 256


def _fail(path, reason: str) -> ConfigError:
    e = ConfigError(f"{path}: {reason}")
    e.path, e.reason = str(path), reason
    return e


def _os_reason(e: OSError) -> str:
    return {errno.ENOENT: "no such file", errno.EACCES: "permission denied", errno.EISDIR: "is a directory",
            errno.ELOOP: "too many symbolic links"}.get(e.errno, e.strerror or type(e).__name__)


def open_regular(path, limit: int, what: str = "file"):
    """An open binary file object for ``path`` when it is a regular file of at most ``limit``
    bytes; else ConfigError("PATH: reason")."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as e:
        raise _fail(path, f"cannot open the {what}: {_os_reason(e)}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode) else (
                "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file")
            raise _fail(path, f"expected a regular {what}, got {kind}")
        if st.st_size > limit:
            raise _fail(path, f"the {what} is {st.st_size} bytes, more than the limit of {limit}")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path, limit: int = MAX_TEXT_BYTES, what: str = "file") -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (see the module docstring)."""
    with open_regular(path, limit, what) as f:
        try:
            data = f.read(limit + 1)
        except OSError as e:
            raise _fail(path, f"cannot read the {what}: {_os_reason(e)}") from None
    if len(data) > limit:
        raise _fail(path, f"the {what} is more than the limit of {limit} bytes")
    return data


def read_text(path, limit: int = MAX_TEXT_BYTES, what: str = "file") -> str:
    """A regular UTF-8 text file (see :func:`read_bytes`)."""
    data = read_bytes(path, limit, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise _fail(path, f"not UTF-8 text (byte {e.start}: {data[e.start:e.start + 1]!r})") from None


# ---------------------------------------------------------------------------------------- run logs

#: the arrays of a run log: name -> (dtype kind, trailing shape); every array has the run's ticks
#: as its first axis. Any other array (metric series ``m_*``, the slave's ``slave_*``, what a newer
#: writer adds) is a name of LOG_NAME and numbers, one row a tick.
LOG_SCHEMA = {
    "t": ("f", ()), "q_r": ("f", (6,)), "q_v_p": ("f", (3,)), "p_r": ("f", (3,)), "R_r": ("f", (3, 3)),
    "R_v": ("f", (3, 3)), "lam": ("f", None), "operator_W": ("f", (6,)), "master_q": ("f", (6,)),
    "can_frames_lost": ("i", ()), "constraint_W": ("f", (6,)), "tick_us": ("f", ()),
}
LOG_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,79}")
REQUIRED = ("t", "p_r", "R_r", "q_v_p", "R_v", "operator_W", "constraint_W", "tick_us")


def _check_zip(path: Path) -> None:
    try:
        with open_regular(path, MAX_LOG_BYTES, "run log") as f, zipfile.ZipFile(f) as z:
            infos = z.infolist()
    except zipfile.BadZipFile as e:
        raise _fail(path, f"not a run log (not an npz archive: {e})") from None
    except OSError as e:
        raise _fail(path, f"cannot read the run log: {_os_reason(e)}") from None
    if len(infos) > MAX_LOG_MEMBERS:
        raise _fail(path, f"not a run log: {len(infos)} members, more than {MAX_LOG_MEMBERS}")
    total = sum(i.file_size for i in infos)
    if total > MAX_LOG_INFLATED_BYTES:
        raise _fail(path, f"the run log inflates to {total} bytes, more than the limit of {MAX_LOG_INFLATED_BYTES}")
    for i in infos:
        name = i.filename[:-4] if i.filename.endswith(".npy") else None
        if name is None or not LOG_NAME.fullmatch(name):
            raise _fail(path, f"not a run log: unexpected member {plain(i.filename)!r}")


def _check_arrays(path: Path, log: dict) -> None:
    for k in REQUIRED:
        if k not in log:
            raise _fail(path, f"not a run log: array {k!r} is missing")
    n = log["t"].shape[0] if log["t"].ndim == 1 else -1
    if n < 0:
        raise _fail(path, f"t: expected shape (n,), got {log['t'].shape}")
    for k, a in log.items():
        kind, tail = LOG_SCHEMA.get(k, ("f", None))
        if not (a.dtype.kind == "f" if kind == "f" else a.dtype.kind in "iu"):
            raise _fail(path, f"{k}: expected {'floats' if kind == 'f' else 'integers'}, got dtype {a.dtype}")
        if a.ndim == 0 or a.shape[0] != n or (tail is not None and a.shape[1:] != tail):
            want = f"({n}, {', '.join(map(str, tail))})" if tail else f"({n}, ...)"
            raise _fail(path, f"{k}: expected shape {want.replace(', )', ')')}, got {a.shape}")
    if n and not (np.isfinite(log["t"]).all() and np.all(np.diff(log["t"]) > 0)):
        raise _fail(path, "t: expected finite, increasing times")


def load_run_log(path) -> tuple[dict, dict]:
    """(arrays, summary) of a run log, every member checked (see the module docstring); any
    problem is one ConfigError naming the file and what is wrong."""
    path = Path(path)
    _check_zip(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            log = {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, KeyError) as e:
        raise _fail(path, f"not a run log: {plain(str(e).splitlines()[0] if str(e) else type(e).__name__)}") from None
    raw = log.pop("summary", None)
    if raw is None or raw.dtype.kind != "U" or raw.shape != ():
        raise _fail(path, "summary: expected the run's JSON summary as a string")
    try:
        summary = json.loads(str(raw))
    except (json.JSONDecodeError, RecursionError) as e:
        raise _fail(path, f"summary: not JSON ({type(e).__name__})") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("scenario"), str):
        raise _fail(path, "summary: expected a table with the scenario's name")
    _check_arrays(path, log)
    return log, summary
