"""Where numba keeps the compiled kernels, so that any user can run teleop.

The kernels are compiled with ``cache=True``; numba writes the cache beside the sources
(``__pycache__``) or under the user's cache folder, and fails at import when it can write to
neither (a package installed by root, run by a user without a writable ``$HOME``). Before numba is
first imported, :func:`choose_cache_dir` picks a writable folder and sets ``NUMBA_CACHE_DIR``:

1. ``NUMBA_CACHE_DIR`` as the user set it, untouched;
2. nothing, when the package's own folder is writable (numba's default, ``__pycache__``);
3. ``$XDG_CACHE_HOME/teleop/numba`` (``~/.cache/teleop/numba``);
4. ``<temp dir>/teleop-numba-<uid>``;
5. none writable: caching off (the kernels compile on every run).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def _writable(folder: Path) -> bool:
    """True when a file can be created in ``folder`` (made if missing)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def candidates() -> list[Path]:
    """The user-wide folders tried, in order, when the package's folder is read-only."""
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return [Path(xdg) / "teleop" / "numba", Path(tempfile.gettempdir()) / f"teleop-numba-{uid}"]


def choose_cache_dir(package_dir: Path = PACKAGE_DIR) -> Path | None:
    """The folder numba should cache in: None for numba's default (the package's ``__pycache__``
    or a folder the user chose through ``NUMBA_CACHE_DIR``), else the first writable candidate.
    Raises nothing; returns ``Path("")`` when nothing is writable (caching off)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    if _writable(package_dir / "dynamics" / "kernels" / "__pycache__"):
        return None
    for folder in candidates():
        if _writable(folder):
            return folder
    return Path("")


def configure() -> Path | None:
    """Apply :func:`choose_cache_dir` (see the module docstring); returns the folder chosen."""
    folder = choose_cache_dir()
    if folder is None:
        return None
    if str(folder):
        os.environ["NUMBA_CACHE_DIR"] = str(folder)
        if "numba" in sys.modules:  # imported before teleop: numba read its settings already
            sys.modules["numba"].config.CACHE_DIR = str(folder)
        return folder
    import numba.core.dispatcher  # nothing writable: compile on every run rather than fail

    numba.core.dispatcher.Dispatcher.enable_caching = lambda self: None
    return folder


def load_cached_kernels(prefix: str = "teleop.") -> int:
    """Load every type signature this machine's cache holds for the compiled kernels of the
    loaded modules named ``prefix``...: a kernel loads once per signature, 5-130 ms, and one first
    met mid-run stalls a real-time loop that long (a kernel called only in contact, on the first
    touch). Reads numba's cache index, which numba keeps per kernel and empties when the kernel's
    source changes; a cache it cannot read loads nothing. Returns how many signatures it loaded."""
    return sum(_load_signatures(kernel) for kernel in compiled_kernels(prefix).values())


def compiled_kernels(prefix: str = "teleop.") -> dict[str, object]:
    """The compiled (numba) kernels of the loaded modules named ``prefix``..., by qualified name
    (module.attribute; a kernel imported into several modules is listed under each)."""
    from numba.core.registry import CPUDispatcher

    return {f"{name}.{attr}": obj for name, module in list(sys.modules.items())
            if name.startswith(prefix) and module is not None
            for attr, obj in list(vars(module).items()) if isinstance(obj, CPUDispatcher)}


def _load_signatures(kernel) -> int:
    """The cached signatures of one kernel that it has not loaded yet, loaded (those numba's own
    index keys to this machine's code generator and this kernel's code); how many."""
    try:  # numba's cache internals: another numba version may lay them out otherwise
        cache, codegen = kernel._cache, kernel.targetctx.codegen()
        wanted = [key[0] for key in cache._cache_file._load_index()
                  if key[0] not in kernel.overloads and key == cache._index_key(key[0], codegen)]
    except Exception:  # a cache it cannot read: nothing to load, the run goes on
        return 0
    n = 0
    for sig in wanted:
        try:
            kernel.compile(sig)
            n += 1
        except Exception:  # an entry numba can neither load nor compile: met, if ever, when called
            pass
    return n
