"""Tissue and contact models that turn the slave tool's motion into forces."""

from teleop.contact.cutting import CuttingModel
from teleop.contact.tissue import ContactReport, SurfaceTissue, TissueBlock

__all__ = ["ContactReport", "CuttingModel", "SurfaceTissue", "TissueBlock"]
