"""model.profile.whole_unit_rates: a joint's synchronised profile in a drive's whole position units never
arrives later than the leading joint, whatever the travel (down to a count) and the move's duration."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from payload_agent.model.profile import synchronised_profiles, trapezoid_duration, whole_unit_rates

CPR = 10430.378  # counts per rad of a 16-bit-per-turn encoder through a 1:1 gear (65536 / 2π)


@settings(max_examples=200, deadline=None)
@given(lead=st.floats(0.01, 3.0), fraction=st.floats(0.0, 1.0), speed=st.floats(0.05, 3.0),
       accel=st.floats(0.2, 20.0))
def test_whole_count_rates_never_make_a_joint_late(lead, fraction, speed, accel):
    q0, q1 = [0.0, 0.0], [lead, lead * fraction]
    prof = synchronised_profiles(q0, q1, speed, accel, [3.0, 3.0], [20.0, 20.0])
    for j in range(2):
        travel = round(q1[j] * CPR)
        v, a = whole_unit_rates(prof.speeds_rad_s[j] * CPR, prof.accels_rad_s2[j] * CPR, travel, prof.duration_s)
        assert isinstance(v, int) and isinstance(a, int) and v >= 1 and a >= 1
        assert v >= prof.speeds_rad_s[j] * CPR and a >= prof.accels_rad_s2[j] * CPR  # rounded up, never down
        assert trapezoid_duration(travel, v, a) <= 1.01 * max(prof.duration_s, 1e-3)


def test_a_travel_of_a_few_counts_gets_the_triangle_of_the_moves_duration():
    v, a = whole_unit_rates(0.0, 0.0, 3, 2.0)  # a joint that does not move in the plan but stands 3 counts off
    assert trapezoid_duration(3, v, a) <= 2.0 * 1.01
    assert (v, a) == (max(1, math.ceil(2 * 3 / 2.0)), max(1, math.ceil(4 * 3 / 4.0)))
