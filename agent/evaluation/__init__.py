"""Runs the analysis and solvers on a run folder, applies the quality gates and gain calibration."""
