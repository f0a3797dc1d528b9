"""One self-contained HTML report per run (``RUN_DIR/report.html``), finished or not.

Everything is inside the one file (inline CSS, plots as base64 PNG ``<img>``), so it can be
mailed, archived with the run folder or opened on a machine without payload-agent.

A run with a result shows:

- a header: robot, controller, date, the primary result and the quality verdict;
- the values to type into the controller, in its own units and frame (UR: kg and m; Elite:
  kg and mm; ``payload_agent.output.pendant``), and whether they were written and read back;
- the estimate of every solver with its 95 % interval, and the simulator's truth for
  simulated runs;
- the inertia, where the run has the inertia part (``report_inertia``): the tensor about the centre
  of mass with σ and 95 % intervals, the UR 6-vector, the principal moments with A/B/C, or why it
  was not given;
- the quality checks, failed ones first, each with its unit, and by how much it failed;
- per sweep, the effort of the joints that carry the payload versus the moving joint's
  angle, empty and loaded, with the fitted model ``empty + Y(q)·θ̂`` (θ̂ of the general
  estimate, or of the primary one); the residuals; the history trend with a database.

A run without a result (stopped by an error, Ctrl-C, the supervision, or before its analysis)
gets a report of what was recorded and why it stopped: the reason, the stop report (how fast
the stop went out, acknowledged or not), every sweep's status and samples, and the raw traces.

The report reads the run folder and ``result.json``; it never re-solves.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from payload_agent.configuration.config import Config
from payload_agent.errors import DataError, UnsupportedCapability
from payload_agent.output import report_html as H
from payload_agent.output import report_plots as P
from payload_agent.output.report_inertia import inertia_html
from payload_agent.output.pendant import driver_type_of, pendant_values, write_back_text
from payload_agent.recording.rundata import SweepData, load_manifest, load_phase
from payload_agent.types import SweepKey

REPORT_NAME = "report.html"
RECORDED = ("complete", "aborted", "recording", "incomplete")  # sweeps an unfinished run's report shows


def write_report(run_dir: Path, config: Config, history_db: Path | None = None, out_path: Path | None = None, *,
                 baseline_dir: Path | None = None) -> Path:
    """Write the HTML report of a recorded run; returns its path (default RUN_DIR/report.html).

    ``config`` must be the run's config (``payload_agent.configuration.recorded.parse_recorded_config``
    rebuilds it from the manifest) so the effort gains and kinematics match the analysis.
    ``baseline_dir``: the run folder whose empty phase was subtracted, when not the run's own.
    Without ``result.json`` the report shows what was recorded and why the run stopped.
    Raises DataError if the folder is not a run, UnsupportedCapability if matplotlib is missing.
    """
    try:
        from matplotlib.figure import Figure  # noqa: F401  (imported for the check; used in report_plots)
    except ImportError:
        raise UnsupportedCapability("the HTML report needs matplotlib: pip install 'payload-agent[report]'") from None
    run_dir = Path(run_dir)
    manifest = load_manifest(run_dir)
    result_path = result_file(run_dir)
    result = None
    if result_path is not None:
        try:
            result = json.loads(result_path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise DataError(f"{result_path}: cannot parse ({exc})") from None
    if result is None:
        page = _stopped_page(run_dir, manifest, config, baseline_dir)
    else:
        page = _result_page(run_dir, manifest, result, config, history_db, baseline_dir)
    out = Path(out_path) if out_path is not None else run_dir / REPORT_NAME
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(page, encoding="utf-8")
    tmp.replace(out)
    return out


def result_file(run_dir: Path) -> Path | None:
    """The result a report shows: ``result.json``, else the newest ``result-solve-*.json``, else None."""
    own = Path(run_dir) / "result.json"
    if own.exists():
        return own
    solved = sorted(Path(run_dir).glob("result-solve-*.json"))
    return solved[-1] if solved else None


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


def _load(run_dir: Path, manifest: dict, gains: np.ndarray, baseline_dir: Path | None, statuses, notes: list[str]
          ) -> tuple[dict[SweepKey, SweepData], dict[SweepKey, SweepData]]:
    loaded: dict[SweepKey, SweepData] = {}
    empty: dict[SweepKey, SweepData] = {}
    for phase, src, target in (("loaded", run_dir, loaded), ("empty", baseline_dir or run_dir, empty)):
        try:
            target.update(load_phase(Path(src), phase, gains, manifest if src == run_dir else None,
                                     statuses=statuses))
        except DataError as exc:
            notes.append(f"no {phase} sweeps to plot: {exc}")
    return loaded, empty


def _sweep_figures(loaded, empty, kin, theta, theta_from, statuses_of: dict[str, str],
                   label: str = "with tool") -> list[P.Figure]:
    figures = []
    groups: dict[tuple, list] = {}  # both directions of one sweep share a figure
    for key in sorted(loaded, key=lambda k: (k.pose, k.joint, k.speed_percent, k.direction != "up")):
        groups.setdefault((key.pose, key.joint, key.speed_percent), []).append((key, loaded[key], empty.get(key)))
    for legs in groups.values():
        status = ", ".join(f"{k.direction} {statuses_of[k.name]}" for k, _, _ in legs
                           if statuses_of.get(k.name, "complete") != "complete")
        fig = P.sweep_figure(legs, kin, theta, theta_from, f" — {status}" if status else "", label)
        if fig is not None:
            figures.append(fig)
    return figures


def _result_page(run_dir: Path, manifest: dict, result: dict, config: Config, history_db: Path | None,
                 baseline_dir: Path | None) -> str:
    gains = np.asarray(result.get("gains_nm_per_unit") or config.effort.gains_nm_per_unit, float)
    kin = config.robot.kinematics
    theta, theta_from = _theta(result)
    notes: list[str] = []
    loaded, empty = _load(run_dir, manifest, gains, baseline_dir, ("complete",), notes)
    figures = _sweep_figures(loaded, empty, kin, theta, theta_from, {})
    residual_fig = None
    try:
        residual_fig = P.residual_figure(loaded, empty, kin, theta, theta_from, result, _commands(manifest),
                                         config.robot.joints)
    except DataError as exc:
        notes.append(f"residuals not plotted: {exc}")
    history_rows, trend_fig, this_entry = [], None, None
    if history_db is not None and Path(history_db).exists():
        history_rows, trend_fig, this_entry = _history_part(Path(history_db), config.robot.name,
                                                            {str(run_dir), str(result.get("run_dir", ""))})

    robot = manifest.get("robot", result.get("robot", "?"))
    quality = result.get("quality") or {}
    passed = quality.get("passed") if quality else None
    badge = {True: '<span class="badge pass">quality checks passed</span>',
             False: '<span class="badge fail">quality checks FAILED</span>',
             None: '<span class="badge none">no quality checks</span>'}[passed]
    headline = (f"m = {H.pm(float(result['mass_kg']), result.get('mass_ci95_kg'), 4)} kg &nbsp;·&nbsp; c = ["
                f"{H.e(H.cog_text(result['cog_mm'], result.get('cog_ci95_mm')))}] mm")
    pv = pendant_values(driver_type_of(manifest), float(result["mass_kg"]), result["cog_mm"])
    if passed is False:
        pendant = ('<div class="stopbox">The quality checks failed: do <b>not</b> type these values into the '
                   f'controller. ({H.e(pv.describe())})<br>{H.e(write_back_text(manifest, this_entry))}</div>')
    else:
        where = f"; {pv.screen}" if pv.screen else ""
        script = f'<br>{H.e(pv.script_name)} form: <code>{H.e(pv.script)}</code>' if pv.script else ""
        pendant = (f'<div class="pendant">Values for the {H.e(pv.controller)} ({H.e(pv.frame + where)}): '
                   f'<b>{H.e(pv.pendant_text)}</b>{script}<br>{H.e(write_back_text(manifest, this_entry))}</div>')
    parts = H.head_html(f"Payload report {robot} {H.when_text(manifest)}") + [
        "<header>", f"<h1>Payload identification: {H.e(robot)}</h1>", H.meta_line(manifest, run_dir),
        f'<div class="headline">{headline} {badge}</div>', pendant,
        f'<div class="meta">primary solver: {H.e(result.get("solver", "?"))}; ± = 95 % interval where the solver '
        f'reports one' + (f'; drive gains: {H.e(result["gains_source"])}' if result.get("gains_source") else "")
        + (f'; analysed by <code>solve</code> with baseline {H.e(result["solve"].get("baseline_dir") or "(own)")}'
           if isinstance(result.get("solve"), dict) else "") + '</div>', "</header>"]
    parts += _estimates_html(result, manifest, quality)
    parts += inertia_html(result, manifest)
    parts += H.checks_html(quality)
    all_notes = list(result.get("notes") or []) + notes
    ests = result.get("estimates") or {}
    for name, est in ests.items():
        if name != result.get("solver"):
            all_notes += [f"{name}: {n}" for n in est.get("notes") or []]
    if all_notes:
        parts += ["<h2>Notes</h2>", "<ul>" + "".join(f"<li>{H.e(n)}</li>" for n in all_notes) + "</ul>"]
    if figures:
        parts.append("<h2>Sweeps: effort versus angle</h2>")
        if theta_from:
            parts.append(f'<p class="meta">Model: empty-flange effort + Y(q)·θ̂ with θ̂ from the {H.e(theta_from)} '
                         f'estimate.</p>')
        parts += [H.img(f) for f in figures]
    if residual_fig is not None:
        parts += ["<h2>Residuals</h2>", H.img(residual_fig)]
    if trend_fig is not None:
        parts += ["<h2>History</h2>", H.img(trend_fig),
                  H.table(["#", "time (UTC)", "tool", "solver", "mass [kg]", "cog [mm]", "quality", "applied",
                           "change"], history_rows, left=(1, 2, 3, 6, 7, 8))]
    parts += ["<h2>Recorded sweeps</h2>", *H.sweeps_table(manifest, H.used_samples(manifest, result))]
    return "\n".join(parts + H.footer_html(manifest)) + "\n"


def _estimates_html(result: dict, manifest: dict, quality: dict) -> list[str]:
    ests = result.get("estimates") or {result.get("solver", "primary"): result}
    head = ["solver", "mass [kg]", "cog x [mm]", "cog y [mm]", "cog z [mm]", "condition number"]
    rows, classes = [], []
    for name, est in ests.items():
        ci = est.get("cog_ci95_mm")
        cond = est.get("condition_number")
        rows.append([name + (" (primary)" if name == result.get("solver") else ""),
                     H.pm(float(est["mass_kg"]), est.get("mass_ci95_kg"), 4),
                     *[H.pm(float(est["cog_mm"][i]), None if ci is None else ci[i], 2) for i in range(3)],
                     "–" if cond is None else f"{cond:.3g}"])
        classes.append("primary" if name == result.get("solver") else "")
    truth = manifest.get("simulation_truth")
    if truth:
        rows.append(["simulation truth", f"{truth['mass_kg']:.4f}", *[f"{v:.2f}" for v in truth["cog_mm"]], ""])
        classes.append("")
    parts = ["<h2>Estimate</h2>", H.table(head, rows, row_class=classes)]
    prow = []
    for p, v in sorted((quality.get("per_pose") or {}).items()):
        try:
            ms, cs, cond = v.get("mass_std_kg"), v.get("cog_std_mm"), v.get("condition_number")
            prow.append([f"pose {p}", H.pm(float(v["mass_kg"]), None if ms is None else 1.96 * ms, 4),
                         *[H.pm(float(v["cog_mm"][i]), None if cs is None else 1.96 * cs[i], 2) for i in range(3)],
                         "–" if cond is None else f"{cond:.3g}"])
        except (KeyError, TypeError, IndexError, ValueError):
            continue  # a per-pose entry this report does not understand: leave it out, do not fail
    if prow:
        parts += ["<p class=\"meta\">The general solver on each tool orientation alone (independent estimates):</p>",
                  H.table(head, prow)]
    return parts


def _history_part(db: Path, robot: str, current: set[str]) -> tuple[list, P.Figure | None, Any]:
    from payload_agent.recording import history

    past = P.load_history(db, robot)
    if not past:
        return [], None, None
    flags = {f.entry_id: f for f in history.compare_to_previous(past)}
    this = next((e for e in reversed(past) if e.run_dir in current), None)
    rows = []
    for ent in past[-15:]:
        f = flags.get(ent.id)
        rows.append([str(ent.id), ent.time_utc.replace("T", " ")[:16], ent.tool or "–", ent.solver,
                     H.pm(ent.mass_kg, ent.mass_ci95_kg, 4), H.cog_text(ent.cog_mm, ent.cog_ci95_mm),
                     {True: "passed", False: "FAILED", None: "–"}[ent.quality_passed],
                     "yes" if ent.applied else "no", ", ".join(f.quantities) if f else ""])
    return rows, P.history_figure(past, current), this


def stop_reason(manifest: dict) -> str:
    """Why a run without a result stopped, from its manifest (runner's ``stopped_because``, else the phases)."""
    from payload_agent.output.stop_text import readable

    for key in ("stopped_because", "stop_reason"):
        if manifest.get(key):
            return readable(str(manifest[key]))
    for ph in ("loaded", "empty"):
        status = str(((manifest.get("phases") or {}).get(ph) or {}).get("status", ""))
        if status.startswith("aborted"):
            return f"{ph} run aborted: " + readable(status.removeprefix("aborted").lstrip(": "))
    if manifest.get("finished_utc") or manifest.get("status") == "complete":
        return "the run finished, but its analysis wrote no result.json (run `payload-agent solve` on the folder)"
    return "unknown: the run ended without recording why (the process may have been killed)"


def _stopped_page(run_dir: Path, manifest: dict, config: Config, baseline_dir: Path | None) -> str:
    gains = np.asarray(manifest.get("gains_nm_per_unit") or config.effort.gains_nm_per_unit, float)
    notes: list[str] = []
    loaded, empty = _load(run_dir, manifest, gains, baseline_dir, RECORDED, notes)
    statuses = {str(s.get("name")): str(s.get("status")) for ph in ("loaded", "empty")
                for s in ((manifest.get("phases") or {}).get(ph) or {}).get("sweeps", [])}
    shown = loaded or empty
    figures = _sweep_figures(shown, empty if loaded else {}, config.robot.kinematics, None, "", statuses,
                             "with tool" if loaded else "empty flange")
    robot = manifest.get("robot", "?")
    stop = manifest.get("stop") or next((ph["stop"] for ph in (manifest.get("phases") or {}).values()
                                          if isinstance(ph, dict) and ph.get("stop")), {})
    stop_lines = []
    if stop:
        delay = stop.get("stop_delay_s")
        stop_lines.append(f"Stop: {stop.get('reason', '')}; sent over the {stop.get('via', '?')}"
                          + (f" {1000 * delay:.0f} ms after the fault" if isinstance(delay, (int, float)) else "")
                          + ("; acknowledged by the controller" if stop.get("acknowledged") else
                             "; NOT acknowledged by the controller: check the robot"))
    n_samples = sum(int(s.get("samples") or 0) for ph in ("empty", "loaded")
                    for s in ((manifest.get("phases") or {}).get(ph) or {}).get("sweeps", []))
    parts = H.head_html(f"Stopped run {robot} {H.when_text(manifest)}") + [
        '<header class="stopped">', f"<h1>Payload identification stopped: {H.e(robot)}</h1>",
        H.meta_line(manifest, run_dir),
        f'<div class="headline">No result <span class="badge fail">run did not finish</span></div>',
        f'<div class="stopbox"><b>Why it stopped:</b> {H.e(stop_reason(manifest))}'
        + "".join(f"<br>{H.e(s)}" for s in stop_lines) + "</div>",
        f'<div class="meta">{n_samples} samples were recorded and are kept in the run folder; nothing was written '
        "to the controller.</div>", "</header>",
        "<h2>What was recorded</h2>", *H.sweeps_table(manifest, None)]
    if notes:
        parts += ["<h2>Notes</h2>", "<ul>" + "".join(f"<li>{H.e(n)}</li>" for n in notes) + "</ul>"]
    if figures:
        parts += ["<h2>Recorded sweeps: effort versus angle</h2>", *[H.img(f) for f in figures]]
    return "\n".join(parts + H.footer_html(manifest)) + "\n"


def _commands(manifest: dict) -> dict | None:
    """Each sweep's commanded motion (the constant-speed windows the analysis used), if the manifest has the plan."""
    from payload_agent.analysis.run_deltas import commands_of
    from payload_agent.errors import DataError

    try:
        return commands_of(manifest)
    except DataError:
        return None
