"""What DH-length errors of a simulated arm do to the payload a calibrated run identifies, noise-free, against the
length term the plan and the run carry (issue 22: that term was computed but never run against an arm with errors).

Not a test: it prints a table. Offline recordings (``fakes.offline``, no noise, the YAML's friction) of
sim-ur5e: the drive-gain calibration (``calibration.fit_from_sweeps``, what ``calibrate`` stores: the YAML's
procedure at ``--calibrate-speed`` with the ``--calibrate-with`` reference, the declared joint systematics, so
its joint zeros too), then the tool run of ``--candidate`` with the simulation's payload, its efforts at the
calibrated gains and its angles corrected by the calibration's zeros, solved as the run solves it. Each arm is
the simulated UR5e with its non-zero DH lengths off by a uniform draw within ±``--dh-error-mm``
(``ArmSpec.with_dh_errors``, the stream ``simulation.dh_length_error_mm`` uses); its error minus the exact arm's
is what the lengths did. Beside it: the plan's first-order prediction for the drawn errors
(``general.kinematic_sensitivities`` with the older absorption rule, the tool run's sweeps standing in for the
calibration's; without any; and with the calibration's own measured response, ``calibration_lengths``, which the
plan and the run use when the calibration stored it), and the plan's term at the declared
``robot.kinematics.length_uncertainty_mm``.

Noise-free, the fits' residual weights (and the calibration's zeros' data information) are set by the length
errors themselves, which makes the calibration's response to them nonlinear; ``--noise`` records with the
simulation's noise, common to every arm, as a real calibration's weights are the noise's.

    .venv/bin/python -m benchmarks.length_errors [--arms 12] [--dh-error-mm 0.5] [--noise]
        [--calibrate-procedure NAME|FILE] [--candidate PROCEDURE:SPEED:FROM:TO]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("mass g", "CoM x mm", "CoM y mm", "CoM z mm")


@dataclass(frozen=True)
class Bench:
    """What every arm is calibrated and run with: sim-ur5e's config, the reference and the run's payload
    ((kg, (x, y, z) mm)), the two plans, and whether the recordings carry the simulation's noise."""

    config: Any
    reference: tuple[float, tuple[float, ...]]
    truth: tuple[float, tuple[float, ...]]
    candidate: Any
    cal_plan: Any
    run_plan: Any
    noise: bool


def bench(calibrate_with: str = "5:60,0,80", calibrate_speed: float = 3.0, candidate: str = "j2_quarter:5:0:20",
          noise: bool = False, calibrate_procedure: str | None = None) -> Bench:
    """The set-up of ``main`` (its options as strings, as on the command line)."""
    from payload_agent.calibrate_args import with_procedure
    from payload_agent.configuration.config import load_config
    from payload_agent.evaluation import design
    from payload_agent.motion.planner import make_plan

    config = load_config(ROOT / "configs" / "sim-ur5e.yaml")
    kg, cog = calibrate_with.split(":")
    name, speed, lo, hi = candidate.split(":")
    cand = design.Candidate(float(speed), 25.0, float(lo), float(hi), 1, 100.0, name)
    cal_plan = make_plan(with_procedure(dataclasses.replace(config, procedure=dataclasses.replace(
        config.procedure, speed_percent=calibrate_speed, inertia=None)), calibrate_procedure))
    payload = config.simulation.payload
    return Bench(config, (float(kg), tuple(float(v) for v in cog.split(","))),
                 (payload.mass_kg, tuple(payload.cog_mm)), cand, cal_plan, design.plan_for(config, cand), noise)


def _record(b: Bench, spec, plan, payload):
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import FrictionParams, PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot

    sim = b.config.simulation
    friction = FrictionParams(np.array(sim.coulomb_nm), np.array(sim.viscous_nm_s_rad), np.array(sim.load_ratio))
    noise = dict(noise_nm=sim.noise_nm, noise_rest_nm=sim.noise_rest_nm) if b.noise else {}
    robot = SimRobot(spec, q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.002, seed=1, friction=friction,
                     **noise)
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(payload[0], list(payload[1])))
    return record_plan(robot, plan)[0], empty


def identified(b: Bench, spec, solve=None):
    """The arm ``spec`` calibrated (``fit_from_sweeps``, as ``calibrate`` stores it) and then run: the run's
    (g, mm, mm, mm) by ``solve(deltas, kin)`` (default ``general.solve``), the calibration and the run's deltas."""
    from payload_agent.evaluation import systematics, zero_offsets
    from payload_agent.evaluation.calibration import fit_from_sweeps
    from payload_agent.solvers import general

    decl, ref = b.config.robot.joints, b.reference
    loaded, empty = _record(b, spec, b.cal_plan, ref)
    cal = fit_from_sweeps(loaded, empty, b.config, ref[0], np.asarray(ref[1]) / 1000.0, joints=decl)
    loaded, empty = _record(b, spec, b.run_plan, b.truth)
    scaled = [{k: dataclasses.replace(v, effort_nm=v.effort_nm * np.asarray(cal.scale)) for k, v in phase.items()}
              for phase in (loaded, empty)]
    if cal.zeros is not None:
        scaled = [zero_offsets.corrected(phase, cal.zeros) for phase in scaled]
    deltas = systematics.prepare(*scaled, decl, None).deltas
    est = (solve or general.solve)(deltas, b.config.robot.kinematics)
    return np.array([1000 * est.mass_kg, *(1000 * np.asarray(est.cog_m))]), cal, deltas


def predictions(b: Bench, cal) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The plan's ∂θ/∂p (K × 4) for the run with the plan's weights: older absorption rule ("absorbed"), none
    ("raw") and the calibration's measured response ("measured"); and the map from θ to (g, mm, mm, mm)."""
    from payload_agent.evaluation import design
    from payload_agent.solvers import general

    sim, kin = b.config.simulation, b.config.robot.kinematics
    theta = design.nominal_theta(*b.truth)
    sweeps = design.planned_sweeps(b.run_plan, 0.002)
    groups = general.build_groups(sweeps, kin)
    by_name = {d.key.name: d for d in sweeps}
    w = np.concatenate([np.full(len(g.y), 1.0 / (sim.noise_nm[g.joint] if g.joint == by_name[g.sweep].moving
                                                 else sim.noise_rest_nm[g.joint]) ** 2) for g in groups])
    Y = np.vstack([g.Y for g in groups])
    inv = np.linalg.pinv((Y * w[:, None]).T @ Y)
    older = (tuple(design.nominal_theta(*b.reference)), tuple(cal.fitted_joints))
    S = {"absorbed": general.kinematic_sensitivities(sweeps, kin, groups, w, inv, theta, older),
         "raw": general.kinematic_sensitivities(sweeps, kin, groups, w, inv, theta, None),
         "measured": general.kinematic_sensitivities(sweeps, kin, groups, w, inv, theta, cal.reference)}
    J = np.zeros((3, 4))
    J[:, 0], J[:, 1:] = -theta[1:] / theta[0] ** 2, np.eye(3) / theta[0]
    return S, 1000.0 * np.vstack([np.eye(4)[0], J])


def arm_errors_m(spec, kin) -> np.ndarray:
    """Each length of ``general.length_parameters(kin)``: the arm's minus the nominal UR5e's, m."""
    from payload_agent.fakes.arms import SPECS
    from payload_agent.solvers import general

    return np.array([getattr(spec.dh[i], f"{k}_m") - getattr(SPECS["ur5e"]().dh[i], f"{k}_m")
                     for i, k in general.length_parameters(kin)])


def main(argv: list[str] | None = None) -> int:
    from payload_agent.fakes.arms import DH_ERROR_STREAM, SPECS
    from payload_agent.solvers import general

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--arms", type=int, default=12)
    p.add_argument("--dh-error-mm", type=float, default=0.5)
    p.add_argument("--calibrate-with", default="5:60,0,80", metavar="KG:X,Y,Z")
    p.add_argument("--calibrate-speed", type=float, default=3.0)
    p.add_argument("--candidate", default="j2_quarter:5:0:20", metavar="PROCEDURE:SPEED:FROM:TO")
    p.add_argument("--calibrate-procedure", metavar="NAME|FILE",
                   help="the calibration's procedure (as `calibrate --procedure`; default the YAML's, paper_bd)")
    p.add_argument("--noise", action="store_true",
                   help="record with the simulation's effort noise, the same draws for every arm (they cancel in "
                        "each arm's difference to the exact arm), so that the fits' weights are the noise's as on a "
                        "real arm, not set by the length errors' own residuals")
    args = p.parse_args(argv)
    b = bench(args.calibrate_with, args.calibrate_speed, args.candidate, args.noise, args.calibrate_procedure)
    config, kin, ref, truth, cand = b.config, b.config.robot.kinematics, b.reference, b.truth, b.candidate
    exact, cal, _ = identified(b, SPECS["ur5e"]())
    S, to_units = predictions(b, cal)
    lengths = general.length_parameters(kin)
    declared = config.robot.length_uncertainty_m
    print(f"{'with the simulation noise (common draws)' if args.noise else 'noise-free'}; sim-ur5e, calibrated with "
          f"{ref[0]:g} kg at {ref[1]} mm ({b.cal_plan.procedure.name}, {args.calibrate_speed:g} %), run "
          f"{cand.describe()}; exact arm's own error {np.round(exact - [1000 * truth[0], *truth[1]], 3)}")
    print("the plan's length term at the declared " + f"{1000 * declared:g} mm: " + ", ".join(
        f"{k} " + " / ".join(f"{v:.3f}" for v in declared * np.sqrt(np.sum((S[k] @ to_units.T) ** 2, axis=0)))
        for k in S) + f" ({', '.join(NAMES)})")
    rows = []
    print("\n| arm | length errors mm (" + ", ".join(f"{k}{i + 1}" for i, k in lengths) + ") | actual | plan (absorbed) |"
          " plan (no absorption) | plan (calibration's response) |\n|---|---|---|---|---|---|")
    for arm in range(1, args.arms + 1):
        spec = SPECS["ur5e"]().with_dh_errors(np.random.default_rng((arm, DH_ERROR_STREAM)), args.dh_error_mm / 1000.0)
        dp = arm_errors_m(spec, kin)
        actual = identified(b, spec)[0] - exact
        pred = {k: to_units @ (S[k].T @ dp) for k in S}
        rows.append(np.concatenate([actual, pred["absorbed"], pred["raw"], pred["measured"]]))
        cell = lambda v: " ".join(f"{x:+.3f}" for x in v)  # noqa: E731
        print(f"| {arm} | {cell(1000 * dp)} | {cell(actual)} | {cell(pred['absorbed'])} | {cell(pred['raw'])} "
              f"| {cell(pred['measured'])} |", flush=True)
    R = np.array(rows)
    print(f"\nover {len(R)} arms (uniform ±{args.dh_error_mm:g} mm: std {args.dh_error_mm / np.sqrt(3):.3f} mm per length)")
    print("| quantity | rms actual | rms plan (absorbed) | rms(actual − absorbed) | rms plan (raw) | rms(actual − raw) |"
          " rms plan (calibration's response) | rms(actual − response) |\n|---|---|---|---|---|---|---|---|")
    rms = lambda v: float(np.sqrt(np.mean(v ** 2)))  # noqa: E731
    for k, n in enumerate(NAMES):
        a, pa, pr, pm = R[:, k], R[:, 4 + k], R[:, 8 + k], R[:, 12 + k]
        print(f"| {n} | {rms(a):.3f} | {rms(pa):.3f} | {rms(a - pa):.3f} | {rms(pr):.3f} | {rms(a - pr):.3f} "
              f"| {rms(pm):.3f} | {rms(a - pm):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
