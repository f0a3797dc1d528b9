"""The report's figures: effort versus angle per sweep, residuals, the history trend.

matplotlib's object API with the Agg canvas (no pyplot, no global backend switch), so it works
headless and inside other programs. Legends sit below the axes, never over a title or a data
point, in a font read at the report's size (10 pt at 100 dpi: 14 px, as the body text). Colours
pair by direction: up is the blue family, down the teal family; the tool's traces are dark, the
empty flange's light. The model lines are dashed (up long dashes, down short) in dark orange on a
white halo, on top, so they stay visible over the traces they fit. The history's x axis counts
identifications in whole numbers; runs without ``--tool`` are labelled so.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from payload_agent.errors import DataError
from payload_agent.recording.rundata import SweepData
from payload_agent.types import SweepKey

PLOT_POINTS = 250  # residual points per sweep (evenly spaced): the regressor per point is the slow part
JOINT_SHARE = 0.1  # plot a joint when its model payload torque reaches this share of the sweep's largest
EMPTY_FIT_DEGREE = 6  # smooth empty-flange effort under the plotted model
COLORS = {"empty": "#9ec3e6", "empty_down": "#93d6cc", "loaded": "#1f5fa8", "loaded_down": "#0f7d72",
          "model": "#c55a00", "residual": "#1f5fa8"}
LEGEND_PT = 10  # legend and caption-size text in the figures (the report shows them 1:1 at 100 dpi)
NO_TOOL = "no tool label (run without --tool)"
Z_DATA, Z_MODEL = 2, 3
HALO: list = []  # the model line's white outline (filled on first use: matplotlib is imported lazily)  # the model on top, but thin and dashed: the recorded traces show through its gaps


@dataclass
class Figure:
    title: str
    png: bytes
    caption: str = ""


def _halo() -> list:
    from matplotlib import patheffects

    return [patheffects.withStroke(linewidth=3.4, foreground="white")]


def png(fig) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    return buf.getvalue()


def model_torque(kin, q: np.ndarray, theta: np.ndarray, joints: Sequence[int]) -> np.ndarray:
    """(n, len(joints)) payload torque Y(q)·θ̂."""
    return kin.payload_regressors(q, joints) @ theta


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


def _legend_below(fig, axes, ncols: int = 3) -> None:
    """One legend under the figure. Entries in drawing order, filled column by column: with ``ncols=2`` for
    up-and-down sweeps the first column holds the up leg's traces and the second the down leg's."""
    handles, labels = [], []
    for ax in axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncols=min(ncols, len(labels)), fontsize=LEGEND_PT,
                   frameon=False)


def sweep_figure(legs: list[tuple[SweepKey, SweepData, SweepData | None]], kin, theta: np.ndarray | None,
                 theta_from: str, status: str = "", label: str = "with tool") -> Figure | None:
    """One figure per sweep: both directions on the same axes (their gap is the friction the
    bidirectional combination cancels), each with its own model line when θ̂ is known."""
    from matplotlib.figure import Figure as MplFigure

    from payload_agent.analysis.delta import window_of

    key0, loaded0, _ = legs[0]
    j = key0.joint - 1
    all_joints = list(range(6))
    if theta is not None:
        step = max(1, len(loaded0.q) // 30)  # the model is smooth: a coarse grid decides which joints matter
        amp = np.max(np.abs(model_torque(kin, loaded0.q[::step], theta, all_joints)), axis=0)
        joints = [c for c in all_joints if amp[c] >= JOINT_SHARE * amp.max()] if amp.max() > 0 else [j]
    else:
        joints = sorted({j, 1, 2} & set(all_joints)) if j in (1, 2) else [j]
    joints = joints[:3]
    fig = MplFigure(figsize=(10.5, 4.0), dpi=100, layout="constrained")
    axes = fig.subplots(1, len(joints), squeeze=False)[0]
    two_way = len(legs) > 1
    for n, (key, loaded, empty) in enumerate(legs):
        tag = f" ({key.direction})" if two_way else ""
        down = key.direction == "down" and two_way
        colour = COLORS["loaded_down"] if down else COLORS["loaded"]
        model_x = model_y = None
        if theta is not None and empty is not None:
            try:
                w = window_of(loaded)
            except DataError:
                w = None
            if w is not None:
                q_w = loaded.q[w.slice]
                q_w = q_w[::max(1, len(q_w) // 120)]
                base = _empty_at(empty, q_w[:, j], j, joints)
                ok = ~np.isnan(base[:, 0])
                model_x = np.degrees(q_w[ok][:, j])
                model_y = base[ok] + model_torque(kin, q_w[ok], theta, joints)
        for ax, c in zip(axes, joints):
            if empty is not None:
                ax.plot(np.degrees(empty.q[:, j]), empty.effort_nm[:, c], color=COLORS["empty_down" if down else "empty"],
                        lw=1.0, zorder=Z_DATA - 1, label="empty flange" + tag)
            ax.plot(np.degrees(loaded.q[:, j]), loaded.effort_nm[:, c], color=colour, lw=0.8,
                    zorder=Z_DATA, label=label + tag)
            if model_y is not None and len(model_x):
                ax.plot(model_x, model_y[:, joints.index(c)], color=COLORS["model"], lw=1.8,
                        dashes=(6, 3) if n == 0 else (2, 2), zorder=Z_MODEL, path_effects=_halo(),
                        label=f"empty (smoothed) + model ({theta_from}){tag}")
    for ax, c in zip(axes, joints):
        ax.set_title(f"joint {c + 1}", fontsize=11)
        ax.set_xlabel(f"joint {key0.joint} angle [deg]")
        ax.set_ylabel("effort [N·m]")
        ax.grid(alpha=0.3)
    _legend_below(fig, axes, ncols=2 if two_way else 3)
    name = key0.name.rsplit("-", 1)[0] + (" up and down" if two_way else f" {key0.direction}")
    fig.suptitle(f"sweep {name} ({key0.speed_percent:g} % speed){status}", fontsize=12, x=0.02, ha="left")
    if theta is not None:
        caption = ("Raw effort × gain over the whole move (standstill, ramps and constant speed). The model is the "
                   f"empty-flange effort smoothed by a degree-{EMPTY_FIT_DEGREE} polynomial in the angle plus Y(q)·θ̂, "
                   "drawn dashed over the constant-speed window only."
                   + (" Up and down legs differ by the friction that the bidirectional combination cancels."
                      if two_way else ""))
    else:
        caption = "Raw effort × gain as recorded (no model: the run has no result)."
    return Figure(f"Sweep {name}", png(fig), caption)


def residual_figure(loaded: dict[SweepKey, SweepData], empty: dict[SweepKey, SweepData], kin,
                    theta: np.ndarray | None, theta_from: str, result: dict[str, Any],
                    commands: dict | None = None, joints=None) -> Figure | None:
    """Δτ − Y·θ̂ on the deltas the analysis solved on (``systematics.prepare``: the declared joint stiffness
    ``joints`` compensated first, as ``evaluation.analyse`` does; None: a rigid arm)."""
    from matplotlib.figure import Figure as MplFigure

    from payload_agent.evaluation import systematics
    from payload_agent.solvers.general import GRAVITY_JOINTS, ZERO_ROW_TOL, select_sweeps

    if theta is None or not empty:
        return None
    deltas = systematics.prepare(loaded, empty, systematics.RIGID if joints is None else joints, commands).deltas
    sweeps = select_sweeps(deltas)
    rms_reported = ((result.get("estimates") or {}).get(theta_from) or {}).get("residual_rms_nm") or {}
    if not sweeps:
        return None
    fig = MplFigure(figsize=(10.5, 3.3 * math.ceil(len(sweeps) / 2)), dpi=100, layout="constrained")
    axes = fig.subplots(math.ceil(len(sweeps) / 2), 2, squeeze=False).ravel()
    cmap = ["#1f5fa8", "#e07b00", "#2a9d3c", "#c0392b", "#7b4fa0"]
    for ax, d in zip(axes, sweeps):
        pick = np.linspace(0, len(d.q) - 1, min(len(d.q), PLOT_POINTS)).astype(int)  # enough to see structure
        q = d.q[pick]
        Y = kin.payload_regressors(q, GRAVITY_JOINTS)  # (n, 5, 4)
        x = np.degrees(q[:, d.moving])
        for ci, jj in enumerate(GRAVITY_JOINTS):
            if np.max(np.abs(Y[:, ci, :])) < ZERO_ROW_TOL:
                continue
            r = d.dtau[pick, jj] - Y[:, ci, :] @ theta
            rms = rms_reported.get(f"{d.key.name}/j{jj + 1}", float(np.sqrt(np.mean(r ** 2))))
            ax.plot(x, r, ".", ms=2.5, color=cmap[ci % len(cmap)], alpha=0.7, label=f"j{jj + 1} RMS {rms:.3f} N·m")
        ax.axhline(0.0, color="black", lw=0.8)
        ax.set_title(f"{d.key.name}", fontsize=11)
        ax.set_xlabel(f"joint {d.key.joint} angle [deg]")
        ax.set_ylabel("Δτ − Y·θ̂ [N·m]")
        ax.grid(alpha=0.3)
        # below the axes, not over the points it describes
        ax.legend(fontsize=LEGEND_PT - 1, markerscale=5, loc="upper center", bbox_to_anchor=(0.5, -0.3), ncol=3,
                  frameon=False, handletextpad=0.2, columnspacing=1.0)
    for ax in axes[len(sweeps):]:
        ax.set_visible(False)
    caption = (f"Residual of the loaded-minus-empty torque after the {theta_from} model, on the constant-speed "
               f"samples the general solver uses (combined up/down sweeps where recorded; up to {PLOT_POINTS} evenly "
               "spaced points per sweep are drawn, the RMS is the solver's over all of them). Structure here "
               "means friction or gain error that did not cancel.")
    return Figure("Residuals", png(fig), caption)


def history_figure(past: list, current_run_dirs: set[str]) -> Figure:
    """Mass and centre of mass of every stored identification, per tool, with 95 % bars."""
    from matplotlib.figure import Figure as MplFigure
    from matplotlib.ticker import MaxNLocator

    fig = MplFigure(figsize=(10.5, 5.0), dpi=100, layout="constrained")
    axes = fig.subplots(2, 2, sharex=True).ravel()
    idx = np.arange(1, len(past) + 1)
    tools = sorted({e.tool or NO_TOOL for e in past}, key=lambda t: (t == NO_TOOL, t))
    markers = "osD^v<>"
    for ai, (ax, label) in enumerate(zip(axes, ["mass [kg]", "cog x [mm]", "cog y [mm]", "cog z [mm]"])):
        for ti, tool in enumerate(tools):
            sel = [i for i, e in enumerate(past) if (e.tool or NO_TOOL) == tool]
            vals = [past[i].mass_kg if ai == 0 else past[i].cog_mm[ai - 1] for i in sel]
            errs = [(past[i].mass_ci95_kg if ai == 0 else (past[i].cog_ci95_mm or (np.nan,) * 3)[ai - 1]) or np.nan
                    for i in sel]
            ax.errorbar(idx[sel], vals, yerr=np.nan_to_num(np.asarray(errs, float)), fmt=markers[ti % len(markers)],
                        ms=5, capsize=2, lw=1, label=tool if tool == NO_TOOL else f"tool {tool}")
        cur = [i for i, e in enumerate(past) if e.run_dir in current_run_dirs]
        if cur:
            i = cur[-1]
            v = past[i].mass_kg if ai == 0 else past[i].cog_mm[ai - 1]
            ax.plot([idx[i]], [v], "o", ms=11, mfc="none", mec="#c0392b", mew=1.5, label="this run")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in axes[2:]:
        ax.set_xlabel("identification # (oldest first)")
    handles, labels = axes[0].get_legend_handles_labels()  # markers (lines) come before error bars: reorder
    order = sorted(range(len(labels)), key=lambda i: labels[i] == "this run")
    handles, labels = [handles[i] for i in order], [labels[i] for i in order]
    fig.legend(handles, labels, loc="outside lower center", ncols=min(4, len(labels)), fontsize=LEGEND_PT,
               frameon=False)
    caption = ("Every identification stored for this robot; bars are 95 % intervals. A change flag means the "
               "result moved by more than the combined 95 % interval since the previous result for the same tool.")
    return Figure("History", png(fig), caption)


def load_history(db: Path, robot: str) -> list:
    from payload_agent.recording import history

    return history.entries(db, robot=robot)
