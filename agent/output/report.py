"""One self-contained HTML report per run (``RUN_DIR/report.html``).

Everything is inside the one file (inline CSS, plots as base64 PNG ``<img>``), so it can be
mailed, archived with the run folder or opened on a machine without payload-agent. It shows:

- a header: robot, controller, date, the primary result and the quality verdict;
- the estimate of every solver with its 95 % interval (from ``result.json``), and the
  simulator's truth for simulated runs;
- the quality checks and notes;
- per sweep, the effort of the joints that carry the payload versus the moving joint's
  angle, empty and loaded, with the fitted model ``empty + Y(q)·θ̂`` where θ̂ = [m, m·cx,
  m·cy, m·cz] comes from the general solver's estimate (or, if it has none, the primary's);
- the residuals Δτ − Y(q)·θ̂ on exactly the samples the general solver uses;
- with a history database, the trend of mass and centre of mass over past identifications.

The report reads the run folder and ``result.json``; it never re-solves, so it shows what
was recorded and reported. Plots use matplotlib's object API with the Agg canvas (no pyplot,
no global backend switch), so it works headless and inside other programs.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from payload_agent import __version__
from payload_agent.configuration.config import Config
from payload_agent.errors import DataError, UnsupportedCapability
from payload_agent.types import SweepKey
from payload_agent.recording.rundata import SweepData, load_manifest, load_phase

REPORT_NAME = "report.html"
PLOT_POINTS = 250  # residual points per sweep (evenly spaced): the regressor per point is the slow part
JOINT_SHARE = 0.1
EMPTY_FIT_DEGREE = 6  # smooth empty-flange effort under the plotted model  # plot a joint when its model payload torque reaches this share of the sweep's largest
COLORS = {"empty": "#8c8c8c", "loaded": "#1f5fa8", "model": "#e07b00", "residual": "#1f5fa8"}


@dataclass
class _Figure:
    title: str
    png: bytes
    caption: str = ""


def write_report(run_dir: Path, config: Config, history_db: Path | None = None, out_path: Path | None = None, *,
                 baseline_dir: Path | None = None) -> Path:
    """Write the HTML report of a recorded, analysed run; returns its path (default RUN_DIR/report.html).

    ``config`` must be the run's config (rebuild it from the manifest as ``solve`` does) so the
    effort gains and kinematics match the analysis. ``baseline_dir``: the run folder whose empty
    phase was subtracted, when the run used a stored baseline instead of its own empty phase.
    Raises DataError if the folder is not a run or has no result.json, UnsupportedCapability
    if matplotlib is missing.
    """
    try:
        from matplotlib.figure import Figure  # noqa: F401  (imported for the check; used below)
    except ImportError:
        raise UnsupportedCapability("the HTML report needs matplotlib: pip install 'payload-agent[report]'") from None
    run_dir = Path(run_dir)
    manifest = load_manifest(run_dir)
    result_path = run_dir / "result.json"
    try:
        result = json.loads(result_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{run_dir} has no result.json (the run did not finish its analysis); "
                        f"run `payload-agent solve {run_dir}` first") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{result_path}: cannot parse ({exc})") from None

    # the gains the analysis used (calibrated ones are recorded in result.json), else the config's
    gains = np.asarray(result.get("gains_nm_per_unit") or config.effort.gains_nm_per_unit, float)
    kin = config.robot.kinematics
    theta, theta_from = _theta(result)
    notes: list[str] = []
    loaded = load_phase(run_dir, "loaded", gains, manifest)
    empty_src = Path(baseline_dir) if baseline_dir is not None else run_dir
    try:
        empty = load_phase(empty_src, "empty", gains)
    except DataError as exc:
        empty = {}
        notes.append(f"no empty-flange sweeps to plot: {exc}")

    figures: list[_Figure] = []
    sweeps: dict[tuple, list] = {}  # both directions of one sweep share a figure
    for key in sorted(loaded, key=lambda k: (k.pose, k.joint, k.speed_percent, k.direction != "up")):
        sweeps.setdefault((key.pose, key.joint, key.speed_percent), []).append((key, loaded[key], empty.get(key)))
    for legs in sweeps.values():
        fig = _sweep_figure(legs, kin, theta, theta_from)
        if fig is not None:
            figures.append(fig)
    residual_fig = None
    try:
        residual_fig = _residual_figure(loaded, empty, kin, theta, theta_from, result)
    except DataError as exc:
        notes.append(f"residuals not plotted: {exc}")
    history_rows, trend_fig = [], None
    if history_db is not None:
        history_rows, trend_fig = _history_part(Path(history_db), config.robot.name, str(result.get("run_dir", "")),
                                                run_dir)

    page = _page(manifest, result, figures, residual_fig, trend_fig, history_rows, notes, theta_from, run_dir)
    out = Path(out_path) if out_path is not None else run_dir / REPORT_NAME
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(page, encoding="utf-8")
    tmp.replace(out)
    return out


# -- model ------------------------------------------------------------------------------------
def _theta(result: dict[str, Any]) -> tuple[np.ndarray | None, str]:
    """θ̂ = [m, m·cx, m·cy, m·cz] (SI) of the general estimate, else of the primary one."""
    est = (result.get("estimates") or {}).get("general")
    name = "general"
    if est is None:
        est, name = result, str(result.get("solver", "primary"))
    try:
        m = float(est["mass_kg"])
        c = np.asarray(est["cog_mm"], float) / 1000.0
    except (KeyError, TypeError, ValueError):
        return None, ""
    return np.array([m, *(m * c)]), name


def _model_torque(kin, q: np.ndarray, theta: np.ndarray, joints: Sequence[int]) -> np.ndarray:
    """(n, len(joints)) payload torque Y(q)·θ̂."""
    return np.array([kin.payload_regressor(qi, joints) @ theta for qi in q])


def _empty_at(empty: SweepData, x: np.ndarray, j: int, joints: Sequence[int]) -> np.ndarray:
    """The empty sweep's effort of ``joints`` at angles ``x`` of moving joint ``j``: a smooth
    polynomial in the angle fitted over the empty sweep's constant-speed window (the raw samples
    are noisy; the plotted model should show the model, not the noise). NaN outside the window."""
    from payload_agent.analysis.delta import window_of

    w = window_of(empty)
    xe = empty.q[w.slice, j]
    out = np.full((len(x), len(joints)), np.nan)
    if len(xe) < EMPTY_FIT_DEGREE + 2:
        return out
    inside = (x >= xe.min()) & (x <= xe.max())
    for c, jj in enumerate(joints):
        poly = np.polynomial.Polynomial.fit(xe, empty.effort_nm[w.slice, jj], EMPTY_FIT_DEGREE)
        out[inside, c] = poly(x[inside])
    return out


def _sweep_figure(legs: list[tuple[SweepKey, SweepData, SweepData | None]], kin, theta: np.ndarray | None,
                  theta_from: str) -> _Figure | None:
    """One figure per sweep: both directions on the same axes (their gap is the friction the
    bidirectional combination cancels), each with its own model line."""
    from matplotlib.figure import Figure

    from payload_agent.analysis.delta import window_of

    key0, loaded0, _ = legs[0]
    j = key0.joint - 1
    all_joints = list(range(6))
    if theta is not None:
        step = max(1, len(loaded0.q) // 30)  # the model is smooth: a coarse grid decides which joints matter
        amp = np.max(np.abs(_model_torque(kin, loaded0.q[::step], theta, all_joints)), axis=0)
        joints = [c for c in all_joints if amp[c] >= JOINT_SHARE * amp.max()] if amp.max() > 0 else [j]
    else:
        joints = [j]
    joints = joints[:3]
    fig = Figure(figsize=(10.5, 3.0), dpi=100, layout="constrained")
    axes = fig.subplots(1, len(joints), squeeze=False)[0]
    two_way = len(legs) > 1
    for n, (key, loaded, empty) in enumerate(legs):
        tag = f" ({key.direction})" if two_way else ""
        alpha = 0.8 if n == 0 else 0.45
        model_x = model_y = None
        if theta is not None and empty is not None:
            w = window_of(loaded)
            q_w = loaded.q[w.slice]
            q_w = q_w[::max(1, len(q_w) // 120)]
            base = _empty_at(empty, q_w[:, j], j, joints)
            ok = ~np.isnan(base[:, 0])
            model_x = np.degrees(q_w[ok][:, j])
            model_y = base[ok] + _model_torque(kin, q_w[ok], theta, joints)
        for ax, c in zip(axes, joints):
            if empty is not None:
                ax.plot(np.degrees(empty.q[:, j]), empty.effort_nm[:, c], color=COLORS["empty"], lw=0.6,
                        alpha=alpha, label="empty flange" + tag)
            ax.plot(np.degrees(loaded.q[:, j]), loaded.effort_nm[:, c], color=COLORS["loaded"], lw=0.6,
                    alpha=alpha, label="with tool" + tag)
            if model_y is not None and len(model_x):
                ax.plot(model_x, model_y[:, joints.index(c)], color=COLORS["model"], lw=1.6,
                        ls="--" if n == 0 else ":", label=f"empty (smoothed) + model ({theta_from}){tag}")
    for ax, c in zip(axes, joints):
        ax.set_title(f"joint {c + 1}", fontsize=10)
        ax.set_xlabel(f"joint {key0.joint} angle [deg]")
        ax.set_ylabel("effort [N·m]")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper right", ncols=3 if two_way else len(labels), fontsize=8,
               frameon=False)
    name = key0.name.rsplit("-", 1)[0] + (" up and down" if two_way else f" {key0.direction}")
    fig.suptitle(f"sweep {name} ({key0.speed_percent:g} % speed)", fontsize=11, x=0.02, ha="left")
    caption = ("Raw effort × gain over the whole move (standstill, ramps and constant speed). The model is the "
               f"empty-flange effort smoothed by a degree-{EMPTY_FIT_DEGREE} polynomial in the angle plus Y(q)·θ̂, "
               "drawn over the constant-speed window only."
               + (" Up and down legs differ by the friction that the bidirectional combination cancels."
                  if two_way else ""))
    return _Figure(f"Sweep {name}", _png(fig), caption)


def _residual_figure(loaded: dict[SweepKey, SweepData], empty: dict[SweepKey, SweepData], kin,
                     theta: np.ndarray | None, theta_from: str, result: dict[str, Any]) -> _Figure | None:
    from matplotlib.figure import Figure

    from payload_agent.analysis.combine import add_combined
    from payload_agent.analysis.delta import subtract_all
    from payload_agent.solvers.general import GRAVITY_JOINTS, ZERO_ROW_TOL, select_sweeps

    if theta is None or not empty:
        return None
    deltas, _ = add_combined(subtract_all(loaded, empty))  # what analysis.deltas_for computes, without re-reading
    sweeps = select_sweeps(deltas)
    rms_reported = ((result.get("estimates") or {}).get(theta_from) or {}).get("residual_rms_nm") or {}
    if not sweeps:
        return None
    fig = Figure(figsize=(10.5, 2.6 * math.ceil(len(sweeps) / 2)), dpi=100, layout="constrained")
    axes = fig.subplots(math.ceil(len(sweeps) / 2), 2, squeeze=False).ravel()
    cmap = ["#1f5fa8", "#e07b00", "#2a9d3c", "#c0392b", "#7b4fa0"]
    for ax, d in zip(axes, sweeps):
        pick = np.linspace(0, len(d.q) - 1, min(len(d.q), PLOT_POINTS)).astype(int)  # enough to see structure
        q = d.q[pick]
        Y = np.array([kin.payload_regressor(qi, GRAVITY_JOINTS) for qi in q])  # (n, 5, 4)
        x = np.degrees(q[:, d.moving])
        for ci, jj in enumerate(GRAVITY_JOINTS):
            if np.max(np.abs(Y[:, ci, :])) < ZERO_ROW_TOL:
                continue
            r = d.dtau[pick, jj] - Y[:, ci, :] @ theta
            rms = rms_reported.get(f"{d.key.name}/j{jj + 1}", float(np.sqrt(np.mean(r ** 2))))
            ax.plot(x, r, ".", ms=2.0, color=cmap[ci % len(cmap)], alpha=0.7, label=f"j{jj + 1} (RMS {rms:.3f})")
        ax.axhline(0.0, color="black", lw=0.8)
        ax.set_title(f"{d.key.name}", fontsize=10)
        ax.set_xlabel(f"joint {d.key.joint} angle [deg]")
        ax.set_ylabel("Δτ − Y·θ̂ [N·m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, markerscale=6, loc="upper right", ncol=2)
    for ax in axes[len(sweeps):]:
        ax.set_visible(False)
    caption = (f"Residual of the loaded-minus-empty torque after the {theta_from} model, on the constant-speed "
               f"samples the general solver uses (combined up/down sweeps where recorded; up to {PLOT_POINTS} evenly "
               "spaced points per sweep are drawn, the RMS is the solver's over all of them). Structure here "
               "means friction or gain error that did not cancel.")
    return _Figure("Residuals", _png(fig), caption)


def _history_part(db: Path, robot: str, result_run_dir: str, run_dir: Path) -> tuple[list, _Figure | None]:
    from matplotlib.figure import Figure

    from payload_agent.output import history

    past = history.entries(db, robot=robot)
    if not past:
        return [], None
    flags = {f.entry_id: f for f in history.compare_to_previous(past)}
    fig = Figure(figsize=(10.5, 4.2), dpi=100, layout="constrained")
    axes = fig.subplots(2, 2, sharex=True).ravel()
    idx = np.arange(1, len(past) + 1)
    tools = sorted({e.tool or "(no label)" for e in past})
    markers = "osD^v<>"
    current = {str(run_dir), result_run_dir}
    for ai, (ax, label) in enumerate(zip(axes, ["mass [kg]", "cog x [mm]", "cog y [mm]", "cog z [mm]"])):
        for ti, tool in enumerate(tools):
            sel = [i for i, e in enumerate(past) if (e.tool or "(no label)") == tool]
            vals = [past[i].mass_kg if ai == 0 else past[i].cog_mm[ai - 1] for i in sel]
            errs = [(past[i].mass_ci95_kg if ai == 0 else (past[i].cog_ci95_mm or (np.nan,) * 3)[ai - 1]) or np.nan
                    for i in sel]
            ax.errorbar(idx[sel], vals, yerr=np.nan_to_num(np.asarray(errs, float)), fmt=markers[ti % len(markers)],
                        ms=4, capsize=2, lw=1, label=tool if ai == 0 else None)
        cur = [i for i, e in enumerate(past) if e.run_dir in current]
        if cur:
            i = cur[-1]
            v = past[i].mass_kg if ai == 0 else past[i].cog_mm[ai - 1]
            ax.plot([idx[i]], [v], "o", ms=11, mfc="none", mec="#c0392b", mew=1.5,
                    label="this run" if ai == 0 else None)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[2:]:
        ax.set_xlabel("identification # (oldest first)")
    axes[0].legend(fontsize=8, loc="best")
    rows = []
    for e in past[-15:]:
        f = flags.get(e.id)
        rows.append([str(e.id), e.time_utc.replace("T", " ")[:16], e.tool or "–", e.solver,
                     _pm(e.mass_kg, e.mass_ci95_kg, 4), _cog_text(e.cog_mm, e.cog_ci95_mm),
                     {True: "passed", False: "FAILED", None: "–"}[e.quality_passed], "yes" if e.applied else "no",
                     ", ".join(f.quantities) if f else ""])
    caption = ("Every identification stored for this robot; bars are 95 % intervals. A change flag means the "
               "result moved by more than the combined 95 % interval since the previous result for the same tool.")
    return rows, _Figure("History", _png(fig), caption)


def _png(fig) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    return buf.getvalue()


# -- HTML -------------------------------------------------------------------------------------
_CSS = """
body { font-family: -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif; color: #1d2733;
       max-width: 1120px; margin: 0 auto; padding: 24px; background: #fff; line-height: 1.4; }
header { border-bottom: 3px solid #1f5fa8; margin-bottom: 18px; padding-bottom: 10px; }
h1 { font-size: 24px; margin: 0 0 6px 0; }
h2 { font-size: 18px; margin: 28px 0 8px 0; border-bottom: 1px solid #d5dbe3; padding-bottom: 4px; }
.meta { color: #4b5a6b; font-size: 14px; }
.headline { font-size: 20px; margin: 10px 0 4px 0; }
.badge { display: inline-block; padding: 2px 10px; border-radius: 10px; font-size: 13px; font-weight: 600;
         color: #fff; vertical-align: middle; }
.pass { background: #2a8c3c; } .fail { background: #c0392b; } .none { background: #7b8794; }
table { border-collapse: collapse; margin: 6px 0 10px 0; font-size: 14px; }
th, td { border: 1px solid #d5dbe3; padding: 4px 10px; text-align: right; }
th { background: #eef2f7; } td.l, th.l { text-align: left; }
tr.primary td { font-weight: 600; background: #f6f9fd; }
figure { margin: 12px 0 22px 0; } figure img { max-width: 100%; border: 1px solid #e3e7ed; }
figcaption { color: #4b5a6b; font-size: 13px; margin-top: 4px; }
ul { margin: 4px 0; } footer { color: #7b8794; font-size: 12px; margin-top: 30px; }
"""


def _e(v: Any) -> str:
    return html.escape(str(v), quote=True)


def _pm(value: float, half: float | None, digits: int) -> str:
    if half is None or not math.isfinite(half):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {half:.{digits}f}"


def _cog_text(cog, ci) -> str:
    return ", ".join(_pm(cog[i], None if ci is None else ci[i], 1) for i in range(3))


def _table(head: list[str], rows: list[list[str]], left: Sequence[int] = (0,), row_class: Sequence[str] = ()) -> str:
    def cell(tag, i, v):
        cls = ' class="l"' if i in left else ""
        return f"<{tag}{cls}>{_e(v)}</{tag}>"

    out = ["<table>", "<tr>" + "".join(cell("th", i, h) for i, h in enumerate(head)) + "</tr>"]
    for r, row in enumerate(rows):
        cls = row_class[r] if r < len(row_class) and row_class[r] else ""
        attr = f' class="{cls}"' if cls else ""
        out.append(f"<tr{attr}>" + "".join(cell("td", i, v) for i, v in enumerate(row)) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _img(fig: _Figure) -> str:
    data = base64.b64encode(fig.png).decode("ascii")
    cap = f"<figcaption>{_e(fig.caption)}</figcaption>" if fig.caption else ""
    return f'<figure><img alt="{_e(fig.title)}" src="data:image/png;base64,{data}">{cap}</figure>'


def _page(manifest: dict, result: dict, figures: list[_Figure], residual_fig: _Figure | None,
          trend_fig: _Figure | None, history_rows: list, notes: list[str], theta_from: str, run_dir: Path) -> str:
    robot = manifest.get("robot", result.get("robot", "?"))
    ctrl = manifest.get("controller") or {}
    when = manifest.get("created_utc", "")
    try:
        when_txt = datetime.fromisoformat(when).strftime("%Y-%m-%d %H:%M:%S %Z").strip()
    except (TypeError, ValueError):
        when_txt = str(when)
    quality = result.get("quality") or {}
    passed = quality.get("passed") if quality else None
    badge = {True: '<span class="badge pass">quality checks passed</span>',
             False: '<span class="badge fail">quality checks FAILED</span>',
             None: '<span class="badge none">no quality checks</span>'}[passed]
    ci_m = result.get("mass_ci95_kg")
    ci_c = result.get("cog_ci95_mm")
    headline = (f"m = {_pm(float(result['mass_kg']), ci_m, 4)} kg &nbsp;·&nbsp; c = ["
                f"{_e(_cog_text(result['cog_mm'], ci_c))}] mm")

    parts = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>Payload report {_e(robot)} {_e(when_txt)}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
        "<header>", f"<h1>Payload identification: {_e(robot)}</h1>",
        f'<div class="meta">{_e(when_txt)} · {_e(ctrl.get("vendor", ""))} {_e(ctrl.get("model", ""))}, firmware '
        f'{_e(ctrl.get("firmware", "?"))} · procedure {_e(manifest.get("procedure", "?"))} · run folder '
        f'<code>{_e(run_dir)}</code></div>',
        f'<div class="headline">{headline} {badge}</div>',
        f'<div class="meta">primary solver: {_e(result.get("solver", "?"))}; ± = 95 % interval where the solver '
        f'reports one' + (f'; drive gains: {_e(result["gains_source"])}' if result.get("gains_source") else "")
        + '</div>',
        "</header>",
    ]

    # estimates
    ests = result.get("estimates") or {result.get("solver", "primary"): result}
    head = ["solver", "mass [kg]", "cog x [mm]", "cog y [mm]", "cog z [mm]", "condition number"]
    rows, classes = [], []
    for name, e in ests.items():
        ci = e.get("cog_ci95_mm")
        cond = e.get("condition_number")
        rows.append([name + (" (primary)" if name == result.get("solver") else ""),
                     _pm(float(e["mass_kg"]), e.get("mass_ci95_kg"), 4),
                     *[_pm(float(e["cog_mm"][i]), None if ci is None else ci[i], 2) for i in range(3)],
                     "–" if cond is None else f"{cond:.3g}"])
        classes.append("primary" if name == result.get("solver") else "")
    truth = manifest.get("simulation_truth")
    if truth:
        rows.append(["simulation truth", f"{truth['mass_kg']:.4f}", *[f"{v:.2f}" for v in truth["cog_mm"]], ""])
        classes.append("")
    parts += ["<h2>Estimate</h2>", _table(head, rows, row_class=classes)]
    per_pose = quality.get("per_pose") or {}
    prow = []
    for p, v in sorted(per_pose.items()):
        try:
            ms, cs, cond = v.get("mass_std_kg"), v.get("cog_std_mm"), v.get("condition_number")
            prow.append([f"pose {p}", _pm(float(v["mass_kg"]), None if ms is None else 1.96 * ms, 4),
                         *[_pm(float(v["cog_mm"][i]), None if cs is None else 1.96 * cs[i], 2) for i in range(3)],
                         "–" if cond is None else f"{cond:.3g}"])
        except (KeyError, TypeError, IndexError, ValueError):
            continue  # a per-pose entry this report does not understand: leave it out, do not fail
    if prow:
        parts += ["<p class=\"meta\">The general solver on each tool orientation alone (independent estimates):</p>",
                  _table(head, prow)]

    # quality
    parts.append("<h2>Quality checks</h2>")
    if not quality:
        parts.append("<p>No quality checks were recorded for this result.</p>")
    else:
        qrows = []
        for c in quality.get("checks", []):
            detail = []
            if all(k in c for k in ("difference_kg", "sigma_kg", "z", "limit_z")):
                detail.append(f"Δm = {c['difference_kg']:+.4f} kg, σ = {c['sigma_kg']:.4f} kg, "
                              f"z = {c['z']:+.2f} (limit ±{c['limit_z']:g})")
            elif isinstance(c.get("value"), (int, float)):
                lim = c.get("limit")
                detail.append(f"{c['value']:.4g}" + (f" (limit {lim:.4g})" if isinstance(lim, (int, float)) else ""))
            qrows.append([str(c.get("check", "?")), "passed" if c.get("passed") else "FAILED", "; ".join(detail)])
        prim = quality.get("primary") or {}
        if prim.get("max_residual_rms_nm") is not None:
            qrows.append(["largest residual RMS (primary)", "info", f"{prim['max_residual_rms_nm']:.3f} N·m"])
        if qrows:
            parts.append(_table(["check", "verdict", "detail"], qrows, left=(0, 1, 2)))
        reasons = quality.get("reasons") or []
        if reasons:
            parts.append("<ul>" + "".join(f"<li>{_e(r)}</li>" for r in reasons) + "</ul>")
    all_notes = list(result.get("notes") or []) + notes
    for name, e in ests.items():
        if name != result.get("solver"):
            all_notes += [f"{name}: {n}" for n in e.get("notes") or []]
    if all_notes:
        parts += ["<h2>Notes</h2>", "<ul>" + "".join(f"<li>{_e(n)}</li>" for n in all_notes) + "</ul>"]

    # plots
    if figures:
        parts.append("<h2>Sweeps: effort versus angle</h2>")
        if theta_from:
            parts.append(f'<p class="meta">Model: empty-flange effort + Y(q)·θ̂ with θ̂ from the {_e(theta_from)} '
                         f'estimate.</p>')
        parts += [_img(f) for f in figures]
    if residual_fig is not None:
        parts += ["<h2>Residuals</h2>", _img(residual_fig)]
    if trend_fig is not None:
        parts += ["<h2>History</h2>", _img(trend_fig),
                  _table(["#", "time (UTC)", "tool", "solver", "mass [kg]", "cog [mm]", "quality", "applied",
                          "change"], history_rows, left=(1, 2, 3, 6, 7, 8))]

    # run facts
    phases = manifest.get("phases") or {}
    srows = []
    for ph in ("empty", "loaded"):
        for s in (phases.get(ph) or {}).get("sweeps", []):
            srows.append([ph, s.get("name", ""), s.get("status", ""), str(s.get("samples", "")),
                          str((result.get("samples") or {}).get(s.get("name"), "–") if ph == "loaded" else "")])
    if srows:
        parts += ["<h2>Recorded sweeps</h2>",
                  _table(["phase", "sweep", "status", "samples", "used (primary)"], srows, left=(0, 1, 2))]
    parts += [f"<footer>payload-agent {_e(__version__)} (run recorded with "
              f"{_e(manifest.get('software_version', '?'))}); plan fingerprint "
              f"{_e(manifest.get('plan_fingerprint', '?'))}; report written "
              f"{_e(datetime.now().astimezone().isoformat(timespec='seconds'))}.</footer>",
              "</body>", "</html>"]
    return "\n".join(parts) + "\n"
