"""Payload solvers: turn baseline-subtracted sweeps into mass and centre of mass."""
