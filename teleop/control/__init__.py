"""The master-to-slave side of control: the admittance controller (§III), mapping, clutch."""

from teleop.control.admittance import AdmittanceController, AdmittanceGains, Phi
from teleop.control.clutch import Clutch

__all__ = ["AdmittanceController", "AdmittanceGains", "Clutch", "Phi"]
