"""The drive-gain calibration the calibrating methods share: the reference payload and its fit.

``general-bi-cal`` and ``general-bi-cal-comp`` (``benchmarks.remedies``) both calibrate the drive gains on a
reference run of the same simulated robot, as ``payload-agent calibrate`` would, and use the calibrated
gains, their uncertainty and the reference θ as the agent's analysis does.
"""

from __future__ import annotations

import numpy as np

REFERENCE = (3.0, (0.0, 0.0, 80.0))  # calibration payload: kg, mm in the flange frame


def calibrate(ref: dict, empty: dict, config, unfitted_std: float, decl=None
              ) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Gain scale, relative gain uncertainty and fitted joints from the reference run's sweeps.

    agent/calibration.py fits the joints that carry enough reference torque; as in the agent's
    own analysis (``GainCalibration.gain_rel_std(unfitted=...)``) the others keep their nominal
    gain with ``unfitted_std`` (``declared_unfitted_gain_std``) as its uncertainty. ``decl``
    (``JointSystematicsConfig``): a declared joint stiffness is compensated first, as
    ``calibration.fit_gains`` does (``systematics.prepare``); None: rigid.
    """
    from payload_agent.evaluation import systematics
    from payload_agent.evaluation.calibration import fit_gains_from_deltas

    deltas = systematics.prepare(ref, empty, systematics.RIGID if decl is None else decl).deltas
    scale, scale_std, fitted = fit_gains_from_deltas(deltas, config.robot.kinematics,
                                                     np.asarray(config.effort.gains_nm_per_unit),
                                                     REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0)
    rel_std = np.array([scale_std[j] if j in fitted else unfitted_std for j in range(len(scale))])
    return np.asarray(scale, float), rel_std, tuple(fitted)


def theta_reference() -> list[float]:
    """θ = [m, m·c] of the reference payload (SI)."""
    m_ref = REFERENCE[0]
    return [m_ref, *(m_ref * np.asarray(REFERENCE[1]) / 1000.0)]


__all__ = ["REFERENCE", "calibrate", "theta_reference"]
