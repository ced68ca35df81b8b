"""teleop: teleoperation of surgical-style robots through a constrained haptic reference tool.

The method is Faulring, Lynch, Colgate and Peshkin, "Haptic Interaction With Constrained
Dynamic Systems": a rigid reference tool integrated on its constraint manifold (``dynamics``),
rendered by an admittance controller (``control``) on a cobot reached over CAN (``can``,
``master``), and followed by a slave arm (``slave``).
"""

from importlib.metadata import PackageNotFoundError, version

from teleop.util import numba_cache
from teleop.util.errors import TeleopError

numba_cache.configure()  # before any kernel module imports numba: a writable cache for any user

#: The distribution's name on the package index ("teleop" there is another project).
DISTRIBUTION = "teleop-haptics"

try:
    __version__ = version(DISTRIBUTION)
except PackageNotFoundError:  # a checkout imported without installing it
    __version__ = "0+unknown"

__all__ = ["TeleopError", "__version__"]
