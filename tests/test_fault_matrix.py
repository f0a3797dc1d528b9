"""A fast subset of `python -m benchmarks.fault_matrix`: whole sessions with a fault injected mid-sweep."""

import pytest

from benchmarks.fault_matrix import run_cell, stop_limit_s


@pytest.mark.parametrize("driver, fault", [("elite_ec", "drop_connections"), ("elite_ec", "stall_stream"),
                                           ("canopen", "protective_stop")])
def test_fault_mid_sweep_stops_the_arm_keeps_the_data_and_says_why(driver, fault, tmp_path):
    cell = run_cell(driver, fault, tmp_path)
    assert cell.passed, f"{driver} {fault}: {'; '.join(cell.problems)} (exit {cell.exit_code}: {cell.message})"
    assert cell.stop_s is not None and cell.stop_s < stop_limit_s(fault)
