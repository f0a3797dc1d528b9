"""Stream gaps (a busy host's simulated stream, a congested network): no sample of the deltas may rest on an
interpolation across a gap of the other run or leg, whose one shared error the fit would count many times."""

import numpy as np
import pytest

from payload_agent.analysis.combine import combine_pair
from payload_agent.analysis.delta import DeltaSweep, outside_gaps, subtract
from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData
from payload_agent.types import SweepKey


def _leg(direction: str, x: np.ndarray, rng) -> DeltaSweep:
    q = np.zeros((len(x), 6))
    q[:, 1] = x
    return DeltaSweep(SweepKey("b", 2, direction, 10.0), q, rng.normal(0.0, 0.3, (len(x), 6)), 0.3)


def test_outside_gaps_marks_the_angles_inside_a_hole():
    xs = np.r_[np.linspace(0.0, 0.1, 101), np.linspace(0.2, 0.3, 101)]  # a hole from 0.1 to 0.2 rad
    x = np.array([0.05, 0.1005, 0.15, 0.1995, 0.25])
    assert outside_gaps(x, xs).tolist() == [True, False, False, False, True]


def test_combined_sweep_has_no_point_in_either_legs_gap():
    rng = np.random.default_rng(1)
    up = _leg("up", np.linspace(0.0, 0.3, 301), rng)
    xd = np.linspace(0.0, 0.3, 251)
    down = _leg("down", xd[(xd < 0.1) | (xd > 0.2)], rng)  # the sparser leg, with a hole
    sparse_up = _leg("up", np.r_[np.linspace(0.0, 0.12, 60), np.linspace(0.18, 0.3, 60)], rng)
    for a, b in ((up, down), (sparse_up, _leg("down", np.linspace(0.0, 0.3, 301), rng))):
        x = combine_pair(a, b).q[:, 1]
        assert len(x) > 100
    x = combine_pair(up, down).q[:, 1]
    assert not ((x > 0.101) & (x < 0.199)).any()  # nothing inside the down leg's hole
    # the old uniform grid would have put 40 % of its points into the 0.12–0.18 hole of the sparse leg
    x = combine_pair(sparse_up, _leg("down", np.linspace(0.0, 0.3, 301), rng)).q[:, 1]
    assert not ((x > 0.121) & (x < 0.179)).any()


def test_subtract_leaves_out_loaded_samples_in_the_empty_runs_gap():
    def run(x, name):
        q = np.zeros((len(x), 6))
        q[:, 1] = x
        return SweepData(SweepKey("b", 2, "up", 10.0), x / 0.5, q, np.zeros((len(x), 6)), name)  # 0.5 rad/s

    x = np.linspace(0.0, 0.5, 501)
    hole = (x > 0.2) & (x < 0.3)
    d = subtract(run(x, "loaded"), run(x[~hole], "empty"))
    inside = d.q[:, 1]
    assert not ((inside > 0.201) & (inside < 0.299)).any()
    assert len(inside) > 300
