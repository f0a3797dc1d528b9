"""The report's inertia section: the tensor about the centre of mass with its uncertainty, every controller's form,
or why the inertia was not given.

Reads what the analysis wrote into result.json: ``inertia_com_kgm2`` / ``inertia_com_std_kgm2`` (None when the
quality check refused the inertia), ``inertia`` (the wrist-move analysis: refusal reason, whether the data alone
were physically consistent, the unsupported estimate) or ``inertia_unsupported`` (``import``), and ``forms``
(``output.payload_forms``: the UR 6-vector, the principal moments with A/B/C). A result without any of these
(the inertia part off, older runs) gets no section.
"""

from __future__ import annotations

import math
from typing import Any

from payload_agent.output import report_html as H

_AXES = ("x", "y", "z")


def _num(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _matrix(value: Any) -> list[list[float]] | None:
    """A 3×3 matrix of finite numbers, or None (anything else is left out, never fails the report)."""
    if not isinstance(value, list) or len(value) != 3:
        return None
    rows = []
    for row in value:
        if not isinstance(row, list) or len(row) != 3:
            return None
        nums = [_num(v) for v in row]
        if any(v is None for v in nums):
            return None
        rows.append(nums)
    return rows


def tensor_table(inertia: list[list[float]], std: list[list[float]] | None,
                 truth: list[list[float]] | None = None) -> str:
    """The 3×3 about the centre of mass, each element with its 95 % interval (1.96 σ) and σ; the simulation truth
    beside it where the run has one."""
    head = ["kg·m²"] + [f"{a} (± 95 %)" for a in _AXES]
    rows = []
    for i, a in enumerate(_AXES):
        rows.append([a] + [H.pm(inertia[i][j], None if std is None else 1.96 * std[i][j], 5) for j in range(3)])
    if std is not None:
        for i, a in enumerate(_AXES):
            rows.append([f"σ {a}"] + [f"{std[i][j]:.5f}" for j in range(3)])
    if truth is not None:
        for i, a in enumerate(_AXES):
            rows.append([f"simulation truth {a}"] + [f"{truth[i][j]:.5f}" for j in range(3)])
    return H.table(head, rows)


def inertia_html(result: dict, manifest: dict) -> list[str]:
    """The section's HTML parts (empty list when the result has no inertia part)."""
    info = result.get("inertia") if isinstance(result.get("inertia"), dict) else {}
    unsupported = result.get("inertia_unsupported") if isinstance(result.get("inertia_unsupported"), dict) else {}
    given = _matrix(result.get("inertia_com_kgm2"))
    if not info and not unsupported and given is None:
        return []
    truth = _matrix(((manifest.get("simulation_truth") or {}).get("inertia_com_kgm2")))
    parts = ["<h2>Inertia</h2>"]
    refused = info.get("refused") or unsupported.get("reason")
    if given is None:
        why = refused or "the analysis gave none"
        parts.append(f'<div class="stopbox"><b>Inertia not given</b>: {H.e(why)}. Mass and centre of mass above '
                     "do not depend on it; the controller keeps its own inertia setting.</div>")
        est = _matrix(info.get("estimate_kgm2") or unsupported.get("inertia_com_kgm2"))
        std = _matrix(info.get("std_kgm2") or unsupported.get("inertia_com_std_kgm2"))
        if est is not None:
            parts.append('<p class="meta">What the data gave (not supported, not to be used):</p>')
            parts.append(tensor_table(est, std, truth))
        return parts
    std = _matrix(result.get("inertia_com_std_kgm2"))
    parts.append('<p class="meta">About the centre of mass, flange axes; ± = 95 % interval (1.96 σ).</p>')
    parts.append(tensor_table(given, std, truth))
    if info.get("inconsistency"):
        parts.append(f"<p>The wrist moves alone gave a tensor that is {H.e(info['inconsistency'])}; the one shown "
                     "is the nearest physically possible tensor.</p>")
    forms = result.get("forms") if isinstance(result.get("forms"), dict) else {}
    ur = (forms.get("ur") or {}).get("inertia_kgm2")
    pr = forms.get("principal") or {}
    rows = []
    if isinstance(ur, list) and len(ur) == 6 and all(_num(v) is not None for v in ur):
        rows.append(["UR set_target_payload / setTargetPayload", "[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] at the CoG",
                     "[" + ", ".join(f"{float(v):.5f}" for v in ur) + "] kg·m²"])
    abc, j = pr.get("abc_deg"), pr.get("j_kgm2")
    if isinstance(abc, list) and isinstance(j, list) and len(abc) == 3 and len(j) == 3:
        rows.append(["principal moments (KUKA load data, OPC 40010 LoadType)", "JX, JY, JZ about axes turned by A, B, C",
                     "J = [" + ", ".join(f"{float(v):.5f}" for v in j) + "] kg·m²; A, B, C = "
                     + ", ".join(f"{float(v):.1f}" for v in abc) + " °"])
    if rows:
        parts.append(H.table(["controller", "form", "value"], rows, left=(0, 1, 2)))
    moves = info.get("wrist_moves")
    if isinstance(moves, list) and moves:
        cond = _num(info.get("condition_number"))
        parts.append(f'<p class="meta">From {len(moves)} recorded wrist moves, {H.e(info.get("samples", "?"))} '
                     "samples" + (f", condition number {cond:.3g}" if cond is not None else "") + ".</p>")
    return parts
