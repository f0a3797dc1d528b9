"""Recorded sweeps -> constant-speed windows, baseline-subtracted and direction-combined torques."""
