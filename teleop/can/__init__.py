"""CAN transport: bus timing (frame times, arbitration, load), the in-process lockstep bus,
fault settings, fault confinement (error counters), traffic capture. No device protocol here: the
cobot's (DBC, driver, simulator, python-can plugin) lives in :mod:`teleop.master.cobot`."""

from teleop.can.busmodel import BusModel, BusTiming, compute_cycle_load_pct, compute_frame_time_s
from teleop.can.capture import Capture
from teleop.can.confinement import ErrorCounters
from teleop.can.faults import Faults

__all__ = [
    "BusModel", "BusTiming", "Capture", "ErrorCounters", "Faults", "compute_cycle_load_pct",
    "compute_frame_time_s",
]
