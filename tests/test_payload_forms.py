"""The inertia in every controller's form: the same tensor, written four ways, reads back the same."""

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from payload_agent.output.payload_forms import payload_forms, principal_axes


def test_a_tensor_diagonal_in_flange_axes_has_no_rotation_and_each_form_keeps_its_order():
    inertia = np.diag([0.02, 0.05, 0.03])
    inertia[0, 1] = inertia[1, 0] = 0.0
    f = payload_forms(2.0, (0.01, -0.02, 0.08), inertia)
    assert f["principal"]["abc_deg"] == [0.0, 0.0, 0.0] or np.allclose(f["principal"]["abc_deg"], 0)
    assert np.allclose(f["principal"]["j_kgm2"], [0.02, 0.05, 0.03])
    assert f["principal"]["xyz_mm"] == [10.0, -20.0, 80.0]
    t = np.array([[0.03, -0.004, 0.002], [-0.004, 0.05, 0.001], [0.002, 0.001, 0.02]])
    f = payload_forms(1.0, (0, 0, 0.1), t)
    assert f["ur"]["inertia_kgm2"] == [0.03, 0.05, 0.02, -0.004, 0.002, 0.001]  # Ixx, Iyy, Izz, Ixy, Ixz, Iyz
    assert np.allclose(np.array(f["franka"]["inertia_column_major_kgm2"]).reshape(3, 3, order="F"), t)
    assert "inertia_kgm2" not in payload_forms(1.0, (0, 0, 0.1), None)["ur"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.005, 0.2), min_size=3, max_size=3),
       st.lists(st.floats(-170, 170), min_size=3, max_size=3))
def test_principal_moments_and_abc_rebuild_the_tensor(moments, abc):
    R = Rotation.from_euler("ZYX", abc, degrees=True).as_matrix()
    tensor = R @ np.diag(moments) @ R.T
    f = payload_forms(1.0, (0, 0, 0), tensor)["principal"]
    R2 = Rotation.from_euler("ZYX", f["abc_deg"], degrees=True).as_matrix()
    np.testing.assert_allclose(R2 @ np.diag(f["j_kgm2"]) @ R2.T, tensor, atol=1e-9)
    m, Rp = principal_axes(tensor)
    assert np.linalg.det(Rp) > 0 and np.arccos(np.clip((np.trace(Rp) - 1) / 2, -1, 1)) <= np.pi / 2 + 1e-9
