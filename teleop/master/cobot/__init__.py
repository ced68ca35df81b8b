"""The cobot master: its protocol (DBC, frame database, codecs, host driver, python-can plugin),
its model, the host controller (:class:`CobotMaster`), and the simulated device on the other side
of the bus (plant and simulator)."""

from teleop.master.cobot.host import CobotMaster
from teleop.master.cobot.model import CobotModel
from teleop.master.cobot.plant import CobotPlant, DeviceParams

__all__ = ["CobotMaster", "CobotModel", "CobotPlant", "DeviceParams"]
