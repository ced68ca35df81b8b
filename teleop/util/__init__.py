"""Utilities every layer may use: errors, typed settings, inputs, resources, the numba cache,
CRC-32 and record views. Nothing here imports another teleop package."""
