"""The CAN link: frame database (DBC + cantools), host driver, device simulator, bus timing, faults."""

from teleop.can.busmodel import BusModel, BusTiming, compute_cycle_load_pct, compute_frame_time_s
from teleop.can.capture import Capture
from teleop.can.database import FrameDatabase
from teleop.can.driver import CobotDriver
from teleop.can.faults import Faults
from teleop.can.simulator import CobotSimulator

__all__ = ["BusModel", "BusTiming", "compute_cycle_load_pct", "compute_frame_time_s", "Capture",
           "FrameDatabase", "CobotDriver", "Faults", "CobotSimulator"]
