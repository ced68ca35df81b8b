"""What a run writes: checked before the run starts, written whole or not at all.

* :func:`check_json_target` - ``--json PATH`` ("-": stdout): its folder exists (or is made) and is
  writable, the path is not a folder; :func:`write_json` writes through a temporary file renamed
  into place, with the mode a new file gets (0644 under the usual umask 022), not mkstemp's 0600.
* :func:`study_folder` - where a study tool (``tools/*.py``) writes when its ``--out`` is not
  given: a new ``runs/<tool>-<date>-<time>/`` of the current folder, never a tracked file.
* :class:`RunFolder` - ``--out DIR``: locked (a second run on the same folder refuses: an
  ``flock`` on ``.DIR.lock`` beside it, released when the process ends however it ends), written
  into a temporary folder beside it and renamed into place by :meth:`RunFolder.commit` once every
  file is there (the summary, ``metrics.json``, last). An existing DIR is replaced only when it is
  empty or holds a previous run (a ``metrics.json``); anything else is refused.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from teleop.util.errors import ConfigError

SUMMARY = "metrics.json"


def check_folder(folder: Path, flag: str, target) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{flag} {target}: cannot make the folder {folder}: {e.strerror}") from None
    if not folder.is_dir():
        raise ConfigError(f"{flag} {target}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"{flag} {target}: the folder {folder} is not writable")


def check_json_target(path: str, flag: str = "--json") -> Path | None:
    """The file of ``flag`` (--json), checked before the run (None for "-", stdout)."""
    if path == "-":
        return None
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{flag} {path}: is a folder; give a file name")
    if p.exists() and not p.is_file():
        raise ConfigError(f"{flag} {path}: exists and is not a regular file")
    check_folder(p.parent if str(p.parent) else Path("."), flag, path)
    return p


def _umask() -> int:
    """The process's umask: read from /proc on Linux (setting it to read it back is not thread-safe)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_json(path: Path, data: dict) -> None:
    """Write JSON whole: a temporary file in the same folder, renamed over ``path``; the file gets
    the mode ``open`` would have given it (0666 less the umask), not mkstemp's private 0600."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(data, indent=2) + "\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


#: where the study tools write by default (relative to the current folder; ``/runs/`` is ignored by git)
RUNS_DIR = "runs"


def study_folder(tool: str, out: str | None = None, now: float | None = None) -> Path:
    """The folder a study tool writes: ``out`` when given (made if missing), else a new
    ``runs/<tool>-YYYYmmdd-HHMMSS/`` of the current folder (``-2``, ``-3``, ... when two runs start
    in the same second). Study results go into ``docs/`` only when ``--out`` says so."""
    if out:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        return folder
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    base = Path(RUNS_DIR) / f"{tool}-{stamp}"
    for k in range(1, 1000):
        folder = base if k == 1 else base.with_name(f"{base.name}-{k}")
        try:
            folder.mkdir(parents=True)
            return folder
        except FileExistsError:
            continue
    raise ConfigError(f"{base}: cannot make a new run folder there (999 taken)")


def out_help(tool: str, what: str) -> str:
    """The ``--out`` help of a study tool: what it writes and the default folder."""
    return (f"folder for {what} (default: a new {RUNS_DIR}/{tool}-DATE-TIME/ here; the published "
            f"results in docs/ are rewritten only when --out names them)")


class RunFolder:
    """``--out DIR`` (see the module docstring): ``path(name)`` a file in the temporary folder,
    ``commit()`` renames it into place, ``abort()`` removes it; both release the lock."""

    def __init__(self, out, flag: str = "--out"):
        self.out = Path(out).resolve()
        self.flag = flag
        if self.out == Path.cwd() or self.out.parent == self.out:
            raise ConfigError(f"{flag} {out}: give a folder of its own for the run (it is replaced whole)")
        parent = self.out.parent
        check_folder(parent, flag, out)
        if self.out.exists() and not self.out.is_dir():
            raise ConfigError(f"{flag} {out}: exists and is not a folder")
        self._lock_path = parent / f".{self.out.name}.lock"
        try:
            self._lock = open(self._lock_path, "a")  # held for the run, closed in _release
        except OSError as e:
            raise ConfigError(f"{flag} {out}: cannot write beside it ({self._lock_path}: {e.strerror})") from None
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            raise ConfigError(f"{flag} {out}: another run is writing this folder (lock {self._lock_path})") from None
        if self.out.is_dir() and any(self.out.iterdir()) and not (self.out / SUMMARY).is_file():
            self._release()
            raise ConfigError(f"{flag} {out}: the folder holds other files and no teleop run ({SUMMARY}); "
                              "choose a new or empty folder")
        try:
            self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.partial-", dir=parent))
            self.tmp.chmod(0o777 & ~_umask())  # mkdtemp's 0700 -> what mkdir would have given
        except OSError as e:
            self._release()
            raise ConfigError(f"{flag} {out}: cannot write beside it ({e.strerror})") from None

    def path(self, name: str) -> Path:
        return self.tmp / name

    def commit(self) -> Path:
        """Rename the finished folder into place (replacing an earlier run there); returns it."""
        old = None
        if self.out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.old-", dir=self.tmp.parent))
            os.replace(self.out, old / "run")
        os.replace(self.tmp, self.out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        self._release()
        return self.out

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        self._release()

    def _release(self) -> None:
        if not self._lock.closed:
            self._lock_path.unlink(missing_ok=True)
            self._lock.close()
