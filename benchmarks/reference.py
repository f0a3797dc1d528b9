"""The drive-gain calibration the calibrating methods share: the reference payload and its fit.

``general-bi-cal`` and ``general-bi-cal-comp`` (``benchmarks.remedies``) both calibrate the drive gains on a
reference run of the same simulated robot through the function ``payload-agent calibrate`` stores the result of
(``calibration.fit_from_sweeps``), and use the calibrated gains, their uncertainty and the reference θ as the
agent's analysis does.
"""

from __future__ import annotations

import numpy as np

REFERENCE = (3.0, (0.0, 0.0, 80.0))  # calibration payload: kg, mm in the flange frame


def calibration(ref: dict, empty: dict, config, decl=None):
    """The product's calibration (``calibration.fit_from_sweeps``, what ``payload-agent calibrate`` stores) of the
    reference run's sweeps against the shared baseline: gains, zeros and the reference run's friction change.

    ``decl`` (``JointSystematicsConfig``): what the agent declares (its stiffness compensated first, its zero and
    friction-change uncertainties the priors); None: rigid, nothing declared."""
    from payload_agent.evaluation import systematics
    from payload_agent.evaluation.calibration import fit_from_sweeps

    return fit_from_sweeps(ref, empty, config, REFERENCE[0], np.asarray(REFERENCE[1]) / 1000.0,
                           joints=systematics.RIGID if decl is None else decl)


def calibrate(ref: dict, empty: dict, config, unfitted_std: float, decl=None
              ) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Gain scale, relative gain uncertainty and fitted joints of ``calibration``.

    As in the agent's own analysis (``GainCalibration.gain_rel_std(unfitted=...)``) the joints the calibration
    does not fit keep their nominal gain with ``unfitted_std`` (``declared_unfitted_gain_std``) as its uncertainty.
    """
    cal = calibration(ref, empty, config, decl)
    return np.asarray(cal.scale, float), np.asarray(cal.gain_rel_std(unfitted_std), float), tuple(cal.fitted_joints)


def theta_reference() -> list[float]:
    """θ = [m, m·c] of the reference payload (SI)."""
    m_ref = REFERENCE[0]
    return [m_ref, *(m_ref * np.asarray(REFERENCE[1]) / 1000.0)]


__all__ = ["REFERENCE", "calibration", "calibrate", "theta_reference"]
