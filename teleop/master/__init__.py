"""The cobot master: device model and simulation, its configuration, the master chain."""

from teleop.master.cobot import CobotDevice, CobotModel, DeviceParams
from teleop.master.cobot_master import CobotMaster
from teleop.master.config import CobotConfig

__all__ = ["CobotConfig", "CobotMaster", "CobotDevice", "CobotModel", "DeviceParams"]
