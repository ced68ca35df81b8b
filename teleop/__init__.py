"""teleop: teleoperation of surgical-style robots through a constrained haptic reference tool.

The method is Faulring, Lynch, Colgate and Peshkin, "Haptic Interaction With Constrained
Dynamic Systems": a rigid reference tool integrated on its constraint manifold (``dynamics``),
rendered by an admittance controller (``control``) on a cobot reached over CAN (``can``,
``master``), and followed by a slave arm (``slave``).
"""

from teleop.errors import TeleopError

__all__ = ["TeleopError"]
__version__ = "0.1.0"
