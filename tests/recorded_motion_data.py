"""Synthetic UR recordings of one excitation motion, empty and loaded, in the RTDE CSV layouts.

What a real UR10e log holds (shared/realdata's README, "Format"): controller time, actual_q,
actual_qd, actual_current, target_current, target_moment, about 100 Hz with jitter. The arm's
own torque is a smooth function of the motion that the agent never sees (it cancels); the
payload's torque comes from its ten inertial parameters (``PAYLOAD``, which the importer is not
told); friction changes a little between the runs; the controller's target moment leaves the
payload out (it was not entered) and its target current adds a friction feed-forward; the
measured current has noise. The loaded run starts later, so only the joint angles align them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from payload_agent.model.kinematics import DHRow, Kinematics
from payload_agent.solvers.regressor import payload_regressor

UR10E = Kinematics([DHRow(0, .1807, np.pi / 2), DHRow(-.6127, 0, 0), DHRow(-.57155, 0, 0),
                    DHRow(0, .17415, np.pi / 2), DHRow(0, .11985, -np.pi / 2), DHRow(0, .11655, 0)])
K_TRUE = np.array([11.5, 12.0, 9.8, 9.0, 8.5, 8.0])  # N·m/A, the drives' real constants
MASS, COG_M = 2.4, np.array([0.02, -0.03, 0.09])
INERTIA_COM = np.array([[0.030, 0.002, -0.003], [0.002, 0.045, 0.004], [-0.003, 0.004, 0.020]])
COLUMNS = "timestamp,actual_q[6],actual_qd[6],actual_current[6],target_current[6],target_moment[6]"
HEADER = ",".join(["timestamp"] + [f"{n}_{k}" for n in ("actual_q", "actual_qd", "actual_current", "target_current",
                                                      "target_moment") for k in range(6)])


def payload_theta() -> np.ndarray:
    """θ = [m, m·c, I about the flange origin (xx, xy, xz, yy, yz, zz)] of ``PAYLOAD``."""
    c = COG_M
    io = INERTIA_COM + MASS * (np.dot(c, c) * np.eye(3) - np.outer(c, c))
    return np.array([MASS, *(MASS * c), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])


def trajectory(t: np.ndarray, duration_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth Fourier excitation of all six joints about a pose clear of singularities."""
    base = np.array([0.0, -1.3, 1.2, -1.4, -1.57, 0.0])
    amp = np.array([0.5, 0.35, 0.45, 0.8, 0.8, 1.2])
    w = 2 * np.pi * np.array([0.11, 0.17, 0.13, 0.23, 0.19, 0.29])
    ramp = np.clip(t / 2.0, 0, 1) ** 2 * np.clip((duration_s - t) / 2.0, 0, 1) ** 2  # still at both ends
    q = base + amp * np.sin(w * t[:, None]) * ramp[:, None]
    qd = np.gradient(q, t, axis=0)
    qdd = np.gradient(qd, t, axis=0)
    return q, qd, qdd


def recording(loaded: bool, seed: int, duration_s: float = 24.0, start_s: float = 100.0) -> np.ndarray:
    """Rows of the 31-column layout (time, q, qd, current, target current, target moment)."""
    rng = np.random.default_rng(seed)
    n = int(duration_s / 0.01)
    t = np.cumsum(rng.uniform(0.006, 0.014, n))  # jittery rows, about 100 Hz
    t = t[t - t[0] <= duration_s] - t[0]
    q, qd, qdd = trajectory(t, duration_s)
    arm = 40 * np.cos(q + 0.3) + 3 * qdd + 5 * np.sin(2 * q)  # the arm's own torque: cancels, never modelled
    arm[:, 3:] *= 0.1
    coulomb = np.array([6.0, 8.0, 5.0, 1.5, 1.5, 1.0]) * (1.05 if loaded else 1.0)
    viscous = np.array([4.0, 5.0, 3.0, 0.8, 0.8, 0.6])
    friction = coulomb * np.sign(qd) + viscous * qd
    tau = arm + friction
    if loaded:
        tau = tau + np.einsum("njk,k->nj", payload_regressor(UR10E, q, qd, qdd), payload_theta())
    current = tau / K_TRUE + rng.normal(0, 0.03, tau.shape)
    target_moment = arm  # the controller's model: no payload entered, no friction
    target_current = (target_moment + 0.9 * friction) / K_TRUE + rng.normal(0, 0.005, tau.shape)
    q_meas = q + rng.normal(0, 2e-5, q.shape)
    return np.column_stack([start_s + t, q_meas, qd, current, target_current, target_moment])


def write(path: Path, rows: np.ndarray, header: bool, rubbish_rows: int = 0) -> Path:
    """The rows as a comma-separated file, with an RTDE header (ur-rtde's form) or none; ``rubbish_rows``
    short and absurd rows first, as a recorder attaching mid-package writes."""
    lines = [HEADER] if header else []
    for k in range(rubbish_rows):
        lines.append("1.2e+308,0.5" if k % 2 == 0 else ",".join(["9e9"] * rows.shape[1]))
    lines += [",".join(f"{v:.6f}" for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def pair(folder: Path, header: bool = False, rubbish_rows: int = 0, seed: int = 1) -> tuple[Path, Path]:
    """An empty and a loaded recording of the same motion; the loaded one starts 0.7 s later in its file."""
    empty = recording(False, seed)
    loaded = recording(True, seed + 1, start_s=400.0)
    lead = np.column_stack([np.arange(70) * 0.01 + 399.3, np.repeat(loaded[:1, 1:], 70, axis=0)])
    loaded = np.vstack([lead, loaded])  # standing still before the motion starts
    return (write(folder / "empty.csv", empty, header, rubbish_rows),
            write(folder / "loaded.csv", loaded, header, 0))
