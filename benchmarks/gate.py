"""The agent's quality gate as benchmark columns: whether it passed and which checks refused."""

from __future__ import annotations

from typing import Any


def gate(deltas: dict, kin, est, **kw) -> dict:
    """The agent's own quality gate (``quality.evaluate``) on the deltas and uncertainty terms a method used.

    ``kw``: ``gain_rel_std``, ``length_std_m``, ``gain_reference`` and ``systematics``, passed as
    ``evaluation.analyse.analyse`` passes them. A crash of the gate is a refusal, reported by name.
    """
    from payload_agent.evaluation import quality

    try:
        q = quality.evaluate(deltas, kin, est, **kw)
    except Exception as exc:  # noqa: BLE001 - a crash of the gate is a refusal, reported by name
        return {"gate_passed": False, "gate_failed": [f"gate raised {type(exc).__name__}: {exc}"]}
    return columns(q)


def columns(q: dict[str, Any]) -> dict:
    """A quality result as the benchmark's columns: passed, the names of what failed (checks, and reasons
    that belong to no check, such as a pose that cannot be solved on its own), every check's value, the cable
    check's numbers."""
    from payload_agent.evaluation import cable_check

    failed = [c["check"] for c in q.get("checks", []) if not c.get("passed")]
    listed = {c.get("reason") for c in q.get("checks", []) if not c.get("passed")}
    failed += [r.split(" (")[0] for r in q.get("reasons", []) if r not in listed]  # without the numbers
    out = {"gate_passed": bool(q.get("passed")), "gate_failed": failed,
           "gate_values": {c["check"]: c["value"] for c in q.get("checks", [])}}
    cable = next((c for c in q.get("checks", []) if c["check"] == cable_check.NAME), None)
    if cable is not None:
        out["cable"] = {k: cable.get(k) for k in ("chi2", "chi2_limit", "mass_shift_g", "cog_shift_mm", "passed")}
    return out


__all__ = ["gate", "columns"]
