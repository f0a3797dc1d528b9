"""The three-step solver's noise covariance counts how the deltas' noise is made (``DeltaSweep.noise_map``).

A combined sweep's samples are the legs' and the empty run's samples interpolated onto one grid, so neighbouring
samples share noise; across a gap of a run's sample stream a whole run of them shares one error. The residuals'
Bartlett kernel alone counts those as independent observations (its σ ran 3–7 % low on the benchmark's dense
streams, most on the CoM y; far lower with gaps). Real physics (MuJoCo EC66, exact payload), the noise added
offline to one noiseless recording so that many draws cost no simulation (docs/benchmarks.md, "Session 17")."""

import dataclasses

import numpy as np
import pytest

from benchmarks.cable_false_alarms import kept
from conftest import tweak
from payload_agent.analysis.combine import add_combined
from payload_agent.analysis.delta import subtract_all
from payload_agent.configuration.config import parse_config
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import three_step

TRUTH = PayloadTruth.point(2.3, (70.0, 65.0, 50.0))
NOISE_NM = 0.3  # the benchmark's sensor noise per sample


@pytest.fixture(scope="module")
def noiseless():
    import yaml
    from conftest import ROOT

    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    cfg = parse_config(tweak(tweak(data, "procedure.speed_percent", 10), "procedure.inertia", False))
    plan = make_plan(cfg)
    robot = SimRobot(ec66_spec(), q0_rad=np.radians(cfg.simulation.start_deg), tick_s=0.008, noise_nm=0.0, seed=0)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(TRUTH)
    loaded, _ = record_plan(robot, plan)
    return cfg.robot.kinematics, loaded, empty


def _noisy(sweeps: dict, rng: np.random.Generator, gap_rate: float) -> dict:
    """Each sweep with white effort noise and, at ``gap_rate`` > 0, random stream gaps (its ends recorded)."""
    out = {}
    for key, sd in sweeps.items():
        keep = kept(len(sd.t), rng, gap_rate) if gap_rate > 0 else np.ones(len(sd.t), bool)
        keep[:5] = keep[-5:] = True
        effort = sd.effort_nm[keep] + rng.normal(0.0, NOISE_NM, (int(keep.sum()), 6))
        out[key] = dataclasses.replace(sd, t=sd.t[keep], q=sd.q[keep], effort_nm=effort)
    return out


def _chi2(noiseless, gap_rate: float, draws: int) -> tuple[np.ndarray, np.ndarray]:
    """Per draw, the error's χ² (4 degrees of freedom, β = [m, x, y, z]) against the solver's covariance: with the
    deltas' noise maps, and with the maps removed (the residuals' kernel alone, as before)."""
    kin, loaded, empty = noiseless
    truth = np.array([TRUTH.mass_kg, *np.asarray(TRUTH.cog_m)])
    rng = np.random.default_rng(11)
    new, old = [], []
    for _ in range(draws):
        deltas, _ = add_combined(subtract_all(_noisy(loaded, rng, gap_rate), _noisy(empty, rng, gap_rate)))
        for out, ds in ((new, deltas), (old, {k: dataclasses.replace(d, noise_map=None) for k, d in deltas.items()})):
            est = three_step.solve(ds, kin)
            e = np.array([est.mass_kg, *est.cog_m]) - truth
            m, c = est.mass_kg, np.asarray(est.cog_m)
            J = np.zeros((4, 4))  # θ = [m, m·c] -> β = [m, c]
            J[0, 0], J[1:, 0], J[1:, 1:] = 1.0, -c / m, np.eye(3) / m
            cov = J @ np.asarray(est.covariance)[:4, :4] @ J.T
            out.append(float(e @ np.linalg.solve(cov, e)))
    return np.array(new), np.array(old)


def test_the_noiseless_recording_is_solved_exactly(noiseless):
    kin, loaded, empty = noiseless
    deltas, _ = add_combined(subtract_all(loaded, empty))
    est = three_step.solve(deltas, kin)
    assert abs(est.mass_kg - TRUTH.mass_kg) < 2e-4  # kg: far below the noise's σ (~8 g)
    np.testing.assert_allclose(est.cog_m, TRUTH.cog_m, atol=1e-4)


def test_gappy_stream_chi2_is_calibrated_where_the_kernel_alone_was_not(noiseless):
    # gap rate 0.05 keeps about half of each run's samples (the loaded host's simulated UR); a right covariance
    # gives a mean χ² of 4 (± 0.4 over 50 draws); the kernel alone counted each gap's shared error many times
    new, old = _chi2(noiseless, 0.05, 50)
    assert 2.8 < new.mean() < 5.4, new.mean()
    assert old.mean() > 1.4 * new.mean(), (old.mean(), new.mean())
