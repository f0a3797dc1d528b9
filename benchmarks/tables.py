"""Summary rows, the printed table and the error-vs-speed figure of the accuracy benchmark."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

EXCITATION_LABEL = "excitation"
DEFAULT_LABEL = "default"


def _order_key(label: str) -> tuple:
    if label == EXCITATION_LABEL:
        return (2, 0.0)
    if label == DEFAULT_LABEL:
        return (1, 0.0)
    return (0, float(label))


def summarize(rows: list[dict], scenarios: Sequence[str], methods: Sequence[str]) -> list[dict]:
    """One summary row per (scenario, procedure, method), in the given scenario and method order."""
    out = []
    keys = sorted({(r["scenario"], r["procedure"], r["method"]) for r in rows},
                  key=lambda k: (list(scenarios).index(k[0]), _order_key(k[1]), list(methods).index(k[2])))
    for sc, pr, me in keys:
        rs = [r for r in rows if (r["scenario"], r["procedure"], r["method"]) == (sc, pr, me)]
        ok = [r for r in rs if "error" not in r]
        s = {"scenario": sc, "procedure": pr, "method": me, "cases": len(rs), "failed": len(rs) - len(ok),
             "procedure_settings": rs[0].get("procedure_settings")}
        if pr not in (EXCITATION_LABEL, DEFAULT_LABEL):
            s["speed_percent"] = float(pr)
        if ok:
            dm = np.abs([r["mass_err_g"] for r in ok])
            dc = np.array([r["cog_err_mm"] for r in ok])
            s.update(mass_err_mean_g=float(dm.mean()), mass_err_max_g=float(dm.max()),
                     cog_err_mean_mm=float(dc.mean()), cog_err_max_mm=float(dc.max()),
                     motion_time_s=float(np.mean([r["motion_time_s"] for r in ok])))
            zm = [r["z_mass"] for r in ok if r["z_mass"] is not None]
            zc = [v for r in ok if r["z_cog"] is not None for v in r["z_cog"]]
            s["z_rms_mass"] = float(np.sqrt(np.mean(np.square(zm)))) if zm else None
            s["z_rms_cog"] = float(np.sqrt(np.mean(np.square(zc)))) if zc else None
            cm = [r["mass_in_ci95"] for r in ok if r["mass_in_ci95"] is not None]
            cc = [r["cog_in_ci95"] for r in ok if r["cog_in_ci95"] is not None]
            s["ci95_mass"] = float(np.mean(cm)) if cm else None
            s["ci95_cog"] = float(np.mean(cc)) if cc else None
            gated = [r for r in ok if "gate_passed" in r]
            if gated:  # a method that refused counts as neither pass nor fail of the gate
                s["gate_pass_rate"] = float(np.mean([r["gate_passed"] for r in gated]))
                counts: dict[str, int] = {}
                for r in gated:
                    for name in r["gate_failed"]:
                        counts[name] = counts.get(name, 0) + 1
                s["gate_failures"] = dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
        out.append(s)
    return out


def format_table(summary: list[dict]) -> str:
    head = ["scenario", "procedure", "method", "Δm mean g", "Δm max g", "Δc mean mm", "Δc max mm",
            "motion s", "rms(err/σ) m", "rms(err/σ) c", "in 95% m", "in 95% c", "gate pass", "failed"]
    lines = []
    for s in summary:
        def f(key, fmt="{:.1f}"):
            v = s.get(key)
            return "-" if v is None else fmt.format(v)
        label = s["procedure"] if "speed_percent" not in s else f"{s['speed_percent']:g} %"
        lines.append([s["scenario"], label, s["method"], f("mass_err_mean_g"),
                      f("mass_err_max_g"), f("cog_err_mean_mm", "{:.2f}"), f("cog_err_max_mm", "{:.2f}"),
                      f("motion_time_s", "{:.0f}"), f("z_rms_mass", "{:.2f}"), f("z_rms_cog", "{:.2f}"),
                      f("ci95_mass", "{:.2f}"), f("ci95_cog", "{:.2f}"), f("gate_pass_rate", "{:.2f}"),
                      f"{s['failed']}/{s['cases']}"])
    widths = [max(len(r[i]) for r in [head, *lines]) for i in range(len(head))]
    text = ["| " + " | ".join(h.ljust(w) for h, w in zip(head, widths)) + " |",
            "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    text += ["| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |" for r in lines]
    return "\n".join(text)


def plot(summary: list[dict], path: Path, default_speed: float | None, scenarios: Sequence[str],
         methods: Sequence[str]) -> None:
    """Mean error vs sweep speed per method: mass and CoM panels, one row per scenario."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    scenarios = [sc for sc in scenarios if any(s["scenario"] == sc for s in summary)]
    fig, axes = plt.subplots(len(scenarios), 2, figsize=(11, 4 * len(scenarios)), squeeze=False)
    colors = dict(zip(methods, ("tab:red", "tab:orange", "tab:blue", "tab:green", "tab:gray", "tab:purple")))
    for r, sc in enumerate(scenarios):
        for c, (key, unit) in enumerate((("mass_err_mean_g", "mean |Δm| (g)"), ("cog_err_mean_mm", "mean CoM error (mm)"))):
            ax = axes[r][c]
            for me in methods:
                pts = sorted((s["speed_percent"], s[key]) for s in summary
                             if s["scenario"] == sc and s["method"] == me and "speed_percent" in s and key in s)
                if pts:
                    ax.plot(*zip(*pts), "o-", color=colors[me], label=me)
                dyn = [s[key] for s in summary if s["scenario"] == sc and s["method"] == me
                       and s["procedure"] == EXCITATION_LABEL and key in s]
                if dyn:
                    ax.axhline(dyn[0], color=colors[me], ls="--", label=f"{me} (excitation, speed-independent)")
                dflt = [s[key] for s in summary if s["scenario"] == sc and s["method"] == me
                        and s["procedure"] == DEFAULT_LABEL and key in s]
                if dflt and default_speed is not None:
                    ax.plot([default_speed], dflt, "*", ms=14, color=colors[me], mec="k",
                            label=f"{me} (default procedure)")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xticks([1, 2, 5, 10, 20])
            ax.set_xticklabels(["1", "2", "5", "10", "20"])
            ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
            ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_xlabel("sweep speed (% of 144 °/s)")
            ax.set_ylabel(unit)
            ax.set_title(f"{sc}: {unit.split(' (')[0]}")
            ax.grid(True, which="both", alpha=0.3)
        axes[r][1].legend(fontsize=7, loc="best")
    fig.suptitle("payload-agent accuracy benchmark, simulated EC66")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
