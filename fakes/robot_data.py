"""Robot data for the simulator's physics: standard DH rows, link inertias, joint limits.

Data only. Every number group names its source; docs/sources.md ("Robot data") lists them too.

Conventions (shared with payload_agent.model.kinematics.DHRow and fakes/physics.build_mjcf):
  DH row i = (a_m, d_m, alpha_rad, theta_offset_rad); frame i from frame i-1 is
      Rz(theta_DH) Tz(d) Tx(a) Rx(alpha),   theta_DH = q_controller + theta_offset.
  Link i is the body moved by joint i; its inertial data are expressed in DH frame i
  (the frame at the distal end of link i):
      mass_kg, com_m = (x, y, z) in DH frame i,
      inertia_kgm2 = (ixx, iyy, izz, ixy, ixz, iyz) about the COM, axes of DH frame i.
  The fixed base link is not listed (it does not move; it never loads a joint).
"""

from __future__ import annotations

import math

# ---------------------------------------------------------------------------------------------
# Elite Robots EC66
# ---------------------------------------------------------------------------------------------
# Kinematics.  Lengths d1=96, a2=418, a3=398, d4=122, d5=98, d6=89 mm (task brief), identical to the
# joint origins in Elite's own URDF:
#   github.com/Elite-Robots/ROS  src/elite_description/urdf/ec66_description.urdf
#   (revision c7d91ae3e5e6c98e740db50c58743221fe2c45da, the newest one; first revision 548d6e89 agrees)
# No Elite-published DH table was found in the searchable sources, so the signs below are derived from
# that URDF.  Base frame = URDF base_link (z up along joint 1).  Joint senses = URDF joint axes, which
# Elite's ROS driver feeds with the controller's angles unchanged (src/elite_driver/src/elite_driver/
# joint_states.py publishes monitor machinePos[:6] in radians, no offset), so URDF q = pendant q.
# Controller zero pose (all joints 0): arm stretched out horizontally along +x of the base, upper arm and
# forearm level at shoulder height; J2, J3, J4 axes along +y, J5 axis along -z, J6/tool axis along -y;
# flange centre at (a2+a3, d4-d6, d1-d5) = (0.816, 0.033, -0.002) m.  Hence all offsets are 0, a2/a3 are
# positive in this base frame, and the wrist twists are both -pi/2 (the EC wrist is mirrored relative to
# the UR one: d6 points back towards the base plane, so the flange sits d4-d6 = 33 mm off the arm plane).
# Cross-check: the robotkinematicscatalogue 1.1.2 (PyPI) Elite EC63/EC612 tables put the flange at
# (a2+a3, d4-d6, d1-d5) at their zero pose, the same layout.  J2 positive tips the upper arm down
# (neobotix/elite-robots2 elite_description/config/joint_limits_ec66.yaml limits J2 to [-180, 0] deg).
# Check (throwaway script): DH flange frame vs URDF "flan" frame over 2000 random q in [-pi, pi]^6:
# max position error 0.48 mm (the c7d91ae URDF has a 0.477 mm z offset in flan_joint; the 548d6e89
# URDF gives 0.012 mm), max orientation error 0.001 deg.
EC66_DH = [
    (0.0, 0.096, -math.pi / 2, 0.0),
    (0.418, 0.0, 0.0, 0.0),
    (0.398, 0.0, 0.0, 0.0),
    (0.0, 0.122, -math.pi / 2, 0.0),
    (0.0, 0.098, -math.pi / 2, 0.0),
    (0.0, 0.089, 0.0, 0.0),
]

# Inertial data: masses, COMs and inertias of link1..link6 from the Elite URDF named above (revision
# c7d91ae), transformed from the URDF link frames into DH frames 1..6 (rotation and translation of each
# URDF link frame relative to DH frame i, taken at q=0 and checked constant over random q).  The 548d6e89
# revision gives the same values to within 0.5 mm / rounding.  The URDF "flan" link (0.105 kg with an
# impossible 1.0 kg*m^2 inertia) is left out.
# UNCERTAIN: the moving links sum to 10.05 kg (10.46 kg with the base), well below the ~17.5 kg arm weight
# usually quoted for the EC66 (not verified here).  The numbers look like CAD volumes at a nominal density:
# another, unattributed SolidWorks export of the EC66 has the same base COM but 1.113 kg instead of
# 0.415 kg (x2.68).  Treat the absolute masses as low; ratios/COMs are likely better than the masses.
EC66_LINKS = [
    {"mass_kg": 1.7827, "com_m": (-4e-06, -0.00284, 0.008261),
     "inertia_kgm2": (0.0031691, 0.0035086, 0.0029334, -2.8351e-08, -1.2175e-07, 0.00037927)},
    {"mass_kg": 4.8843, "com_m": (-0.24163, 3e-06, 0.139318),
     "inertia_kgm2": (0.0066105, 0.022101, 0.022526, 5.143e-08, -0.00021178, 1.2649e-07)},
    {"mass_kg": 2.1495, "com_m": (-0.19731, -6e-06, 0.028008),
     "inertia_kgm2": (0.0015747, 0.0091566, 0.0091573, -5.6762e-08, 7.3471e-05, -1.4788e-07)},
    {"mass_kg": 0.53436, "com_m": (-1e-06, 0.00601, -0.0007),
     "inertia_kgm2": (0.00041486, 0.00037669, 0.0004403, 0.0, -4.9046e-09, 5.8283e-05)},
    {"mass_kg": 0.53436, "com_m": (-1e-06, 0.006003, -0.000703),
     "inertia_kgm2": (0.00041486, 0.00037669, 0.0004403, 0.0, -4.2505e-09, 5.8283e-05)},
    {"mass_kg": 0.16488, "com_m": (-1e-06, 2.3e-05, -0.021169),
     "inertia_kgm2": (7.7869e-05, 7.757e-05, 0.00011744, 0.0, 0.0, -7.8331e-08)},
]

# Joint speed limits: Elite URDF (c7d91ae) <limit velocity> 2.6199, 2.6199, 3.3161, 4.5379, 4.5379, 4.5379
# rad/s, same in src/moveit_config/ec66_moveit_config/config/joint_limits.yaml (2.61993 / 3.31613 /
# 4.53786) and annotated 150 / 190 / 260 deg/s in neobotix/elite-robots2
# elite_description/config/joint_limits_ec66.yaml.  Elite's spec sheet itself was not found.
EC66_MAX_SPEED_DEG_S = [150.0, 150.0, 190.0, 260.0, 260.0, 260.0]
# The paper's "100 %" joint speed for the EC66 (its runs scale from this, not from the limits above).
EC66_SPEED_100PCT_DEG_S = 144.0

# ESTIMATE, not a rating: no Elite-published rated (continuous) joint torque was found.  These are the
# <limit effort> values of the Elite URDF (150 N*m J1-J3, 28 N*m J4-J6).  They equal UR5e's published
# maximum joint torques exactly, so they were probably copied from UR; use them as torque saturation
# levels.  Plausibility: holding 6 kg at full reach with the URDF masses needs ~80 N*m at J2.
EC66_RATED_TORQUE_NM = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]

# ---------------------------------------------------------------------------------------------
# Universal Robots UR5e
# ---------------------------------------------------------------------------------------------
# Kinematics, masses and centres of mass: Universal Robots, "DH Parameters for calculations of
# kinematics and dynamics",
#   https://www.universal-robots.com/articles/ur/application-installation/dh-parameters-for-calculations-of-kinematics-and-dynamics/
# UR5e table: d1=0.1625, a2=-0.425, a3=-0.3922, d4=0.1333, d5=0.0997, d6=0.0996 m,
# alpha = [pi/2, 0, 0, pi/2, -pi/2, 0], theta = 0; controller angles are the DH angles (zero pose:
# arm stretched horizontally).  The same page states the UR3e/UR5e inertia matrices are negligible
# and publishes none.
UR5E_DH = [
    (0.0, 0.1625, math.pi / 2, 0.0),
    (-0.425, 0.0, 0.0, 0.0),
    (-0.3922, 0.0, 0.0, 0.0),
    (0.0, 0.1333, math.pi / 2, 0.0),
    (0.0, 0.0997, -math.pi / 2, 0.0),
    (0.0, 0.0996, 0.0, 0.0),
]

# mass_kg and com_m: UR's page above (COMs are given in the DH frames; values copied unchanged).
# inertia_kgm2: CYLINDER APPROXIMATION.  The tensors of github.com/UniversalRobots/
# Universal_Robots_ROS2_Description config/ur5e/physical_parameters.yaml (commit 2221ec0f, marked
# "generated using cylinder approximation", with the rotations given there), transformed from the URDF
# link frames (urdf/ur_macro.xacro + config/ur5e/default_kinematics.yaml) into DH frames 1..6.  The same
# transformation maps that file's COMs back onto UR's published DH-frame COMs exactly (check passed), and
# its flange frame equals DH frame 6 (error 2e-10 m).
UR5E_LINKS = [
    {"mass_kg": 3.761, "com_m": (0.0, -0.02561, 0.00193),
     "inertia_kgm2": (0.010267, 0.00666, 0.010267, 0.0, 0.0, 0.0)},
    {"mass_kg": 8.058, "com_m": (0.2125, 0.0, 0.11336),
     "inertia_kgm2": (0.015107, 0.13389, 0.13389, 0.0, 0.0, 0.0)},
    {"mass_kg": 2.846, "com_m": (0.15, 0.0, 0.0265),
     "inertia_kgm2": (0.004095, 0.031209, 0.031209, 0.0, 0.0, 0.0)},
    {"mass_kg": 1.37, "com_m": (0.0, -0.0018, 0.01634),
     "inertia_kgm2": (0.0025599, 0.0021942, 0.0025599, 0.0, 0.0, 0.0)},
    {"mass_kg": 1.3, "com_m": (0.0, 0.0018, 0.01634),
     "inertia_kgm2": (0.0025599, 0.0021942, 0.0025599, 0.0, 0.0, 0.0)},
    {"mass_kg": 0.365, "com_m": (0.0, 0.0, -0.001159),
     "inertia_kgm2": (9.8904e-05, 9.8904e-05, 0.00013212, 0.0, 0.0, 0.0)},
]

# 180 deg/s on every joint: UR5e User Manual (e-Series, v5.8), as cited in
# Universal_Robots_ROS2_Description config/ur5e/joint_limits.yaml (max_velocity: !degrees 180.0).
UR5E_MAX_SPEED_DEG_S = [180.0, 180.0, 180.0, 180.0, 180.0, 180.0]
# Maximum joint torques 150/150/150/28/28/28 N*m: UR article "Max. joint torques", as cited in the same
# joint_limits.yaml (max_effort).
UR5E_MAX_TORQUE_NM = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]

# ---------------------------------------------------------------------------------------------
# CANopen arm: a 6-axis arm with Universal Robots UR3e geometry and masses, built from CiA 402
# servo drives (the simulated CANopen arm, fakes/canopen; arms.canopen_arm_spec)
# ---------------------------------------------------------------------------------------------
# Kinematics, masses and centres of mass: Universal Robots, "DH Parameters for calculations of
# kinematics and dynamics" (the page cited for the UR5e above), UR3e table: d1=0.15185, a2=-0.24355,
# a3=-0.2132, d4=0.13105, d5=0.08535, d6=0.0921 m, alpha = [pi/2, 0, 0, pi/2, -pi/2, 0], theta = 0;
# link masses 1.98, 3.4445, 1.437, 0.871, 0.805, 0.261 kg; COMs in the DH frames, copied unchanged.
CANOPEN_ARM_DH = [
    (0.0, 0.15185, math.pi / 2, 0.0),
    (-0.24355, 0.0, 0.0, 0.0),
    (-0.2132, 0.0, 0.0, 0.0),
    (0.0, 0.13105, math.pi / 2, 0.0),
    (0.0, 0.08535, -math.pi / 2, 0.0),
    (0.0, 0.0921, 0.0, 0.0),
]

# inertia_kgm2: APPROXIMATION.  The principal moments of github.com/UniversalRobots/
# Universal_Robots_ROS2_Description config/ur3e/physical_parameters.yaml (commit 3426d674), assigned to
# the DH axes with that file's own COM axis mapping (shoulder and wrist 1: URDF y = -DH z, URDF z = DH y;
# wrist 2: URDF y = DH z, URDF z = -DH y; the others share the DH axes); its products of inertia
# (all below 0.0015 kg*m^2) are dropped.  UR's page calls the UR3e inertias negligible.
CANOPEN_ARM_LINKS = [
    {"mass_kg": 1.98, "com_m": (0.0, -0.02, 0.0), "inertia_kgm2": (0.0027657, 0.0025626, 0.0021501, 0.0, 0.0, 0.0)},
    {"mass_kg": 3.4445, "com_m": (0.13, 0.0, 0.1157),
     "inertia_kgm2": (0.0042623, 0.0460284, 0.0448947, 0.0, 0.0, 0.0)},
    {"mass_kg": 1.437, "com_m": (0.05, 0.0, 0.0238),
     "inertia_kgm2": (0.0010511, 0.0113396, 0.0110895, 0.0, 0.0, 0.0)},
    {"mass_kg": 0.871, "com_m": (0.0, 0.0, 0.01), "inertia_kgm2": (0.0008174, 0.0005497, 0.0006844, 0.0, 0.0, 0.0)},
    {"mass_kg": 0.805, "com_m": (0.0, 0.0, 0.01), "inertia_kgm2": (0.0006059, 0.0003831, 0.0005837, 0.0, 0.0, 0.0)},
    {"mass_kg": 0.261, "com_m": (0.0, 0.0, -0.02), "inertia_kgm2": (0.0001080, 0.0001086, 0.0001371, 0.0, 0.0, 0.0)},
]

# Joint speed limits 180/180/180/360/360/360 deg/s and maximum joint torques 56/56/28/12/12/12 N*m:
# UR3e User Manual (e-Series, v5.8) and the UR article "Max. joint torques", both as cited in
# Universal_Robots_ROS2_Description config/ur3e/joint_limits.yaml (commit 8ef39b34).
CANOPEN_ARM_MAX_SPEED_DEG_S = [180.0, 180.0, 180.0, 360.0, 360.0, 360.0]
# ESTIMATE, not a rating: the simulated drives use the maximum joint torques above as their rated torque
# (0x6076, the scale of the per-mille torque actual value 0x6077).
CANOPEN_ARM_RATED_TORQUE_NM = [56.0, 56.0, 28.0, 12.0, 12.0, 12.0]
