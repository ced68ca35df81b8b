"""The masters: the ideal one and the cobot (host, protocol, simulated device), and its configuration."""

from teleop.master.base import Master
from teleop.master.cobot import CobotMaster, CobotModel, CobotPlant, DeviceParams
from teleop.master.config import CobotConfig
from teleop.master.ideal import IdealMaster

__all__ = ["CobotConfig", "CobotMaster", "CobotModel", "CobotPlant", "DeviceParams", "IdealMaster", "Master"]
