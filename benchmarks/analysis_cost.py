"""What one analysis costs: weighted fits made and wall time of ``evaluation.analyse.analyse``.

Not a test: it prints numbers. Run ``.venv/bin/python -m benchmarks.analysis_cost [--repeat N]``.
A simulated EC66 runs the sim config's procedure offline (``fakes.offline.record_plan``) with every
systematic term active (declared joint stiffness, friction asymmetry, a weak tool cable, a calibration's
drive-gain uncertainty), then the analysis runs N times with ``wls.FitResult`` instrumented.
``tests/test_analysis_core.py`` asserts that no fit is made twice; this prints how many there are.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3, help="analyses timed (default 3; the best is printed)")
    args = p.parse_args(argv)

    import yaml

    from payload_agent.configuration.config import parse_config
    from payload_agent.evaluation.analyse import AnalysisOptions, Gains, analyse
    from payload_agent.fakes.arms import ec66_spec
    from payload_agent.fakes.effects import PhysicsEffects, ToolCable
    from payload_agent.fakes.offline import record_plan
    from payload_agent.fakes.physics import PayloadTruth
    from payload_agent.fakes.sim_robot import SimRobot
    from payload_agent.motion.planner import make_plan
    from payload_agent.solvers import wls

    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text(encoding="utf-8"))
    data["robot"]["kinematics"]["stiffness_nm_per_rad"] = [3e4, 3e4, 3e4, 3e4, 5e3, 5e3]
    data["robot"]["friction_asymmetry_percent"] = 5
    config = parse_config(data)
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=5, noise_nm=0.05,
                     effects=PhysicsEffects(tool_cable=ToolCable((0.05, 0.05, 0.05))))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(2.0, (10.0, -20.0, 60.0)))
    loaded, _ = record_plan(robot, plan)
    options = AnalysisOptions.from_config(config, "general")
    gains = Gains(tuple(config.effort.gains_nm_per_unit), "nominal", rel_std=(0.01,) * 6,
                  reference=((3.0, 0.0, 0.0, 0.24), (1, 2)))

    made: list[tuple[int, int, tuple[str, ...]]] = []  # (parameters, rows, the fit's groups)
    init = wls.FitResult.__init__

    def counting(self, *a, **kw):
        init(self, *a, **kw)
        made.append((len(self.theta), self.n, tuple(self.sigma_nm)))

    wls.FitResult.__init__ = counting
    try:
        times = []
        for _ in range(max(1, args.repeat)):
            made.clear()
            t0 = time.perf_counter()
            result = analyse(loaded, empty, options, gains)
            times.append(time.perf_counter() - t0)
    finally:
        wls.FitResult.__init__ = init
    fits = Counter(made)
    print(f"analysis of one simulated EC66 run ({len(loaded)} loaded sweeps, every systematic term active)")
    print(f"  weighted fits per analysis: {len(made)} ({len(fits)} distinct; most repeated ×{max(fits.values())})")
    for (p, n, labels), k in sorted(fits.items()):
        poses = sorted({label.split("-")[0] for label in labels})
        print(f"    {p:2d} parameters, {n:6d} rows, pose(s) {'+'.join(poses)}: ×{k}")
    print(f"  wall time: best {min(times):.3f} s of {len(times)}")
    print(f"  mass {result.primary.mass_kg:.6f} ± {1.96 * result.primary.mass_std_kg:.6f} kg, "
          f"quality {'passed' if result.quality['passed'] else 'FAILED'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
