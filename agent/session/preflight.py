"""Everything `run` would refuse, checked without connecting: what `plan` and `doctor` validate.

``plan`` must validate everything ``run`` validates, so both call ``preflight``:

- the YAML itself (already parsed: keys, units, duplicates);
- the plan can be made (procedure, kinematics, wrist solutions);
- the driver section and the effort unit (``connection.build_driver``: nothing connects);
- the simulated arm of a ``simulation`` section;
- every sweep stays above the floor and inside the reach box, checked per sweep so that the
  error names the procedure key that moves it there (``procedure.sweep_deg``);
- the rest of the safety gate's plan check (the approach path needs the current angles);
- the stored drive-gain calibration, which a run refuses before moving when it no longer fits.

``Preflight.problems`` are ConfigErrors (key path + sentence); ``require`` raises the first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.errors import ConfigError, DataError, PayloadAgentError
from payload_agent.motion import workspace
from payload_agent.motion.planner import Plan, make_plan
from payload_agent.output.plan_table import loop_sentence
from payload_agent.motion.safety import APPROACH_UNKNOWN, SafetyGate, Verdict


@dataclass
class Preflight:
    plan: Plan | None
    problems: list[ConfigError] = field(default_factory=list)
    verdict: Verdict | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def require(self) -> "Preflight":
        if self.problems:
            raise self.problems[0]
        return self

    def to_json(self) -> dict:
        return {"ok": self.ok, "problems": [{"key": p.key_path, "problem": p.problem, "source": p.source}
                                            for p in self.problems], "notes": self.notes}


def _as_config_error(exc: PayloadAgentError, key: str, source: str) -> ConfigError:
    if isinstance(exc, ConfigError):
        return exc
    return ConfigError(key, str(exc), source)


def sweep_envelope_problems(config: Config, plan: Plan) -> list[ConfigError]:
    """A sweep whose path leaves the floor or the reach box: the error names ``procedure.sweep_deg``."""
    s, kin = config.safety, config.robot.kinematics
    pc = config.procedure
    problems: list[ConfigError] = []
    prev = None
    for m in plan.moves:
        tgt = np.asarray(m.target_rad, float)
        if m.sweep is not None and prev is not None:
            out = workspace.outside_on_path(s, kin, prev, tgt)
            if out is not None:
                where = (f"the sweep {m.label} over procedure.sweep_deg [{pc.sweep_from_deg:g}, {pc.sweep_to_deg:g}]° "
                         f"(joint 1 at procedure.base_deg {pc.base_deg:g}°)")
                hint = ("safety.floor_z_mm: narrow the range (a smaller lower elevation keeps the flange higher)"
                        if out[0] == "floor" else "safety.reach_box_mm")
                problems.append(ConfigError("procedure.sweep_deg", f"{where}: {out[1]}; see {hint}", config.source))
        prev = tgt
    return problems


def capability_problems(config: Config, capabilities: frozenset[str], *, apply: bool, watch: bool) -> list[ConfigError]:
    """What the session's options need from the driver and it cannot do: known before the first move."""
    name = config.driver_type
    out = []
    if (apply or watch) and "write_payload" not in capabilities:
        what = "--apply" if apply else "watch (every run it starts writes the result)"
        out.append(ConfigError("--apply" if apply else "watch", f"driver {name!r} cannot write the payload setting "
                               f"with this configuration, so {what} could never succeed; nothing would be written "
                               "after the whole run. Run without --apply and type the result at the controller",
                               config.source))
    trigger = config.watch.trigger if (watch and config.watch is not None) else None
    need = {"digital_input": "read_digital_input", "register": "read_trigger"}.get(trigger or "")
    if need and need not in capabilities:
        out.append(ConfigError("watch.trigger", f"a {trigger} trigger needs the driver to read "
                               f"{'digital inputs' if trigger == 'digital_input' else 'a tool-change register'}, "
                               f"which driver {name!r} cannot with this configuration; use type: file",
                               config.source))
    return out


def preflight(config: Config, *, calibration: bool = True, apply: bool = False, watch: bool = False) -> Preflight:
    """Every check ``run`` makes before connecting; never connects, never moves.

    ``calibration``: also refuse a stored drive-gain calibration that no longer fits (``doctor``
    reports that one on its own line instead). ``apply`` / ``watch``: the capabilities those need.
    """
    from payload_agent.session.connection import build_driver

    result = Preflight(None)
    try:
        result.plan = make_plan(config)
    except PayloadAgentError as exc:
        result.problems.append(_as_config_error(exc, "procedure", config.source))
    try:
        capabilities = build_driver(config).capabilities()
        result.problems += capability_problems(config, capabilities, apply=apply, watch=watch)
        if "write_payload" not in capabilities:
            result.notes.append(f"driver {config.driver_type!r} cannot write the payload setting: results are "
                                "typed in at the controller (--apply is refused before any motion)")
    except PayloadAgentError as exc:
        result.problems.append(_as_config_error(exc, "driver", config.source))
    if config.simulation is not None:
        try:
            from payload_agent.fakes.arms import SPECS

            if config.simulation.arm not in SPECS:
                result.problems.append(ConfigError("simulation.arm", f"unknown simulated arm "
                                                   f"{config.simulation.arm!r}; known: {', '.join(sorted(SPECS))}",
                                                   config.source))
        except ImportError as exc:
            result.problems.append(ConfigError("simulation", f"the simulated controllers need the 'sim' extra "
                                               f"(pip install 'payload-agent[sim]'): {exc}", config.source))
    if result.plan is not None:
        envelope = sweep_envelope_problems(config, result.plan)
        result.problems += envelope
        result.verdict = SafetyGate(config).check(result.plan, None)
        result.notes.append(loop_sentence(SafetyGate(config).check_loop(result.plan)))
        if not envelope:  # the sweep problems already say it, with the key
            for p in result.verdict.problems:
                if not p.startswith(APPROACH_UNKNOWN):
                    result.problems.append(ConfigError("safety", f"the safety gate refuses the plan: {p}",
                                                       config.source))
    if not calibration:
        return result
    try:
        from payload_agent.evaluation.calibration import effective_gains

        from payload_agent.evaluation.controller_gains import records_controller_targets

        note = effective_gains(config)[1]
        if note is None and records_controller_targets(config.driver_type):  # UR: fitted by the run itself
            note = ("no calibration stored: the controller's own constants, fitted by the run from its "
                    "target_current / target_moment")
        result.notes.append(f"drive gains: {note}" if note else "drive gains: nominal (no calibration stored)")
    except DataError as exc:
        result.problems.append(ConfigError("gains.json", str(exc), config.source))
    return result

