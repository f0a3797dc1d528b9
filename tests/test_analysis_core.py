"""One analysis core: the pure ``analyse`` fits the model once and hands it to every consumer.

A synthetic run (the simulated EC66 recorded offline, a weak tool cable so that the wrist and cable
fits with nuisance offsets have something to find, a declared joint stiffness so that the stiffness
term's finite differences run) is analysed with the fit constructor instrumented: every weighted fit
made during one ``analyse`` is recorded by its shape and its estimate, and no fit may be made twice.
"""

from __future__ import annotations

import builtins
import io

import numpy as np
import pytest
import yaml

from payload_agent.configuration.config import parse_config
from payload_agent.evaluation.analyse import AnalysisOptions, Gains, analyse
from payload_agent.fakes.arms import ec66_spec
from payload_agent.fakes.effects import PhysicsEffects, ToolCable
from payload_agent.fakes.offline import record_plan
from payload_agent.fakes.physics import PayloadTruth
from payload_agent.fakes.sim_robot import SimRobot
from payload_agent.motion.planner import make_plan
from payload_agent.solvers import general, wls
from payload_agent.solvers.fitted import ALL

from conftest import ROOT, tweak


@pytest.fixture(scope="module")
def run():
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "procedure.speed_percent", 20)  # fewer samples: a fast test
    data = tweak(data, "robot.kinematics.stiffness_nm_per_rad", [3e4, 3e4, 3e4, 3e4, 5e3, 5e3])
    data = tweak(data, "robot.friction_asymmetry_percent", 5)
    config = parse_config(data)
    plan = make_plan(config)
    robot = SimRobot(ec66_spec(), q0_rad=np.asarray(plan.moves[0].target_rad), tick_s=0.008, seed=5, noise_nm=0.05,
                     effects=PhysicsEffects(tool_cable=ToolCable((0.05, 0.05, 0.05))))
    empty, _ = record_plan(robot, plan)
    robot.set_payload(PayloadTruth.point(2.0, (10.0, -20.0, 60.0)))
    loaded, _ = record_plan(robot, plan)
    gains = Gains(tuple(config.effort.gains_nm_per_unit), "nominal", rel_std=(0.01,) * 6,
                  reference=((3.0, 0.0, 0.0, 0.24), (1, 2)))
    return loaded, empty, AnalysisOptions.from_config(config), gains


def test_one_fitted_model_and_no_fit_made_twice_per_analysis(run, monkeypatch):
    loaded, empty, options, gains = run
    made: list[tuple] = []  # (parameters, rows, groups, θ̂) of every fit: the same fit made twice repeats all four
    init = wls.FitResult.__init__

    def counting(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append((len(self.theta), self.n, tuple(self.sigma_nm), tuple(np.round(self.theta, 12))))

    models = []
    fit_model = general.fit_model

    def counting_models(*args, **kwargs):
        models.append(fit_model(*args, **kwargs))
        return models[-1]

    monkeypatch.setattr(wls.FitResult, "__init__", counting)
    monkeypatch.setattr(general, "fit_model", counting_models)
    result = analyse(loaded, empty, options, gains)

    assert len(models) == 1, "one fitted model per analysis"
    model = models[0]
    combined = (4, sum(len(g.y) for g in model.groups), tuple(g.label for g in model.groups))
    poses = [(4, sum(len(g.y) for g in model.groups_of(p)), tuple(g.label for g in model.groups_of(p)))
             for p in model.poses]
    shapes = [m[:3] for m in made]  # two fits of one shape differ in their columns (e.g. the gain-scatter fits with
    # and without the calibration's absorption, for the general and the three-step term): only θ̂ tells them apart
    assert shapes.count(combined) == 1, "the combined weighted fit is made exactly once"
    assert len(poses) == 2 and all(shapes.count(p) == 1 for p in poses), "each pose's own fit exactly once"
    repeated = {k: made.count(k) for k in made if made.count(k) > 1}
    assert not repeated, f"fits made more than once: {repeated}"
    assert any(m[0] > 4 for m in made), "the fits with nuisance offsets / gain columns are counted too"
    # and every consumer saw that model: the systematic terms are in the estimate, the gate checked its fits
    assert any("wrist torques" in n for n in result.primary.notes)
    assert set(result.quality["per_pose"]) == set(model.poses)
    assert any(c["check"] == "tool cable / hose on the wrist" and "chi2" in c for c in result.quality["checks"])


def test_analyse_reads_and_writes_no_file(run, monkeypatch):
    """Pure: the same answer with every file closed to it, and the same answer twice."""
    loaded, empty, options, gains = run
    first = analyse(loaded, empty, options, gains).to_json()
    import scipy.special  # noqa: F401  (the cable check's import, done before files are closed)

    def refused(*args, **kwargs):
        raise AssertionError(f"analyse opened a file: {args[:1]}")

    monkeypatch.setattr(builtins, "open", refused)
    monkeypatch.setattr(io, "open", refused)
    again = analyse(loaded, empty, options, gains).to_json()
    assert again == first
    assert first["estimates"].keys() == {"general", "three-step"} and first["solver"] == "general"


def test_solvers_share_one_signature_and_the_model(run):
    """Every solver takes the same arguments; the general one reuses the model instead of refitting."""
    from payload_agent.evaluation import systematics
    from payload_agent.solvers import SOLVERS

    loaded, empty, options, gains = run
    deltas = systematics.prepare(loaded, empty, options.joints).deltas
    model = general.fit_model(deltas, options.kin, gains.rel_std)
    for solver in SOLVERS.values():
        est = solver.solve(deltas, options.kin, gain_rel_std=gains.rel_std, length_std_m=options.length_std_m,
                           gain_reference=gains.reference, model=model)
        assert est.solver == solver.name and est.mass_std_kg > 0
    plain = general.solve(deltas, options.kin, gain_rel_std=gains.rel_std)
    np.testing.assert_array_equal(plain.covariance, general.estimate(model).covariance)
    assert model.fit(ALL) is model.fit(ALL)


def test_an_unknown_solver_is_refused_by_name(run):
    from payload_agent.errors import DataError

    loaded, empty, options, gains = run
    for opts, others in ((AnalysisOptions(options.kin, options.joints, None, "least-squares"), None),
                         (options, ("three-step", "least-squares"))):
        with pytest.raises(DataError, match="unknown solver 'least-squares'; available: general, three-step"):
            analyse(loaded, empty, opts, gains, solvers=others)
