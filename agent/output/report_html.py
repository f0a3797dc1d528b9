"""The report's HTML: one self-contained page (inline CSS, plots as base64 PNG), no scripts, nothing external."""

from __future__ import annotations

import base64
import html
import math
from datetime import datetime
from pathlib import Path
from typing import Any, Sequence

from payload_agent.version import __version__
from payload_agent.output.checks import check_rows
from payload_agent.output.report_plots import Figure

CSS = """
body { font-family: -apple-system, "Segoe UI", Roboto, "DejaVu Sans", Arial, sans-serif; color: #1d2733;
       max-width: 1120px; margin: 0 auto; padding: 24px; background: #fff; line-height: 1.4; }
header { border-bottom: 3px solid #1f5fa8; margin-bottom: 18px; padding-bottom: 10px; }
header.stopped { border-bottom-color: #c0392b; }
h1 { font-size: 24px; margin: 0 0 6px 0; }
h2 { font-size: 18px; margin: 28px 0 8px 0; border-bottom: 1px solid #d5dbe3; padding-bottom: 4px; }
.meta { color: #4b5a6b; font-size: 14px; }
.headline { font-size: 20px; margin: 10px 0 4px 0; }
.badge { display: inline-block; padding: 2px 10px; border-radius: 10px; font-size: 13px; font-weight: 600;
         color: #fff; vertical-align: middle; }
.pass { background: #2a8c3c; } .fail { background: #c0392b; } .none { background: #7b8794; }
.pendant { border: 2px solid #1f5fa8; border-radius: 6px; padding: 8px 14px; margin: 10px 0; background: #f6f9fd; }
.pendant b { font-size: 17px; }
.stopbox { border: 2px solid #c0392b; border-radius: 6px; padding: 8px 14px; margin: 10px 0; background: #fdf3f2; }
table { border-collapse: collapse; margin: 6px 0 10px 0; font-size: 14px; }
th, td { border: 1px solid #d5dbe3; padding: 4px 10px; text-align: right; }
th { background: #eef2f7; } td.l, th.l { text-align: left; }
tr.primary td { font-weight: 600; background: #f6f9fd; }
tr.failed td { background: #fdecea; } tr.failed td.verdict { color: #c0392b; font-weight: 700; }
figure { margin: 12px 0 22px 0; } figure img { max-width: 100%; border: 1px solid #e3e7ed; }
figcaption { color: #4b5a6b; font-size: 13px; margin-top: 4px; }
ul { margin: 4px 0; } footer { color: #7b8794; font-size: 12px; margin-top: 30px; }
"""


def e(v: Any) -> str:
    return html.escape(str(v), quote=True)


def pm(value: float, half: float | None, digits: int) -> str:
    if half is None or not math.isfinite(half):
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {half:.{digits}f}"


def cog_text(cog, ci) -> str:
    return ", ".join(pm(cog[i], None if ci is None else ci[i], 1) for i in range(3))


def table(head: list[str], rows: list[list[str]], left: Sequence[int] = (0,), row_class: Sequence[str] = (),
          cell_class: dict[int, str] | None = None) -> str:
    cell_class = cell_class or {}

    def cell(tag, i, v):
        classes = (["l"] if i in left else []) + ([cell_class[i]] if i in cell_class else [])
        cls = f' class="{" ".join(classes)}"' if classes else ""
        return f"<{tag}{cls}>{e(v)}</{tag}>"

    out = ["<table>", "<tr>" + "".join(cell("th", i, h) for i, h in enumerate(head)) + "</tr>"]
    for r, row in enumerate(rows):
        cls = row_class[r] if r < len(row_class) and row_class[r] else ""
        attr = f' class="{cls}"' if cls else ""
        out.append(f"<tr{attr}>" + "".join(cell("td", i, v) for i, v in enumerate(row)) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def img(fig: Figure) -> str:
    data = base64.b64encode(fig.png).decode("ascii")
    cap = f"<figcaption>{e(fig.caption)}</figcaption>" if fig.caption else ""
    return f'<figure><img alt="{e(fig.title)}" src="data:image/png;base64,{data}">{cap}</figure>'


def when_text(manifest: dict) -> str:
    when = manifest.get("created_utc", "")
    try:
        return datetime.fromisoformat(when).strftime("%Y-%m-%d %H:%M:%S %Z").strip()
    except (TypeError, ValueError):
        return str(when)


def head_html(title: str) -> list[str]:
    return ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">', f"<title>{e(title)}</title>",
            f"<style>{CSS}</style>", "</head>", "<body>"]


def meta_line(manifest: dict, run_dir: Path) -> str:
    ctrl = manifest.get("controller") or {}
    return (f'<div class="meta">{e(when_text(manifest))} · {e(ctrl.get("vendor", ""))} {e(ctrl.get("model", ""))}, '
            f'firmware {e(ctrl.get("firmware", "?"))} · procedure {e(manifest.get("procedure", "?"))} · run folder '
            f'<code>{e(run_dir)}</code></div>')


def footer_html(manifest: dict) -> list[str]:
    return [f"<footer>payload-agent {e(__version__)} (run recorded with "
            f"{e(manifest.get('software_version', '?'))}); plan fingerprint "
            f"{e(manifest.get('plan_fingerprint', '?'))}; report written "
            f"{e(datetime.now().astimezone().isoformat(timespec='seconds'))}.</footer>", "</body>", "</html>"]


def checks_html(quality: dict) -> list[str]:
    """The quality checks: failed ones first and highlighted, each value and limit with its unit, and
    for a failed check by how much it missed."""
    parts = ["<h2>Quality checks</h2>"]
    if not quality:
        return parts + ["<p>No quality checks were recorded for this result.</p>"]
    rows, classes = [], []
    for r in check_rows(quality):
        rows.append([r.name, "passed" if r.passed else "FAILED", r.value, r.limit, r.margin or "–", r.detail])
        classes.append("" if r.passed else "failed")
    prim = quality.get("primary") or {}
    if prim.get("max_residual_rms_nm") is not None:
        rows.append(["largest residual RMS (primary)", "info", f"{prim['max_residual_rms_nm']:.3f} N·m", "", "–", ""])
        classes.append("")
    if rows:
        parts.append(table(["check", "verdict", "value", "limit", "failed by", "detail"], rows,
                           left=(0, 1, 5), row_class=classes, cell_class={1: "verdict"}))
    in_rows = " ".join(r[5] for r in rows)
    other = [r for r in quality.get("reasons") or [] if r not in in_rows]  # reasons no check row carries
    if other:
        parts.append("<ul>" + "".join(f"<li>{e(r)}</li>" for r in other) + "</ul>")
    return parts


def sweeps_table(manifest: dict, used: dict[str, str] | None) -> list[str]:
    """Every recorded sweep: phase, status, samples recorded, samples the primary estimate used (with a
    result), stream gaps (where the recorder kept stream statistics)."""
    rows = []
    any_stream = False
    for ph in ("empty", "loaded"):
        for s in ((manifest.get("phases") or {}).get(ph) or {}).get("sweeps", []):
            gaps = (s.get("stream") or {}).get("gaps") or []
            any_stream = any_stream or "stream" in s
            row = [ph, s.get("name", ""), s.get("status", ""), str(s.get("samples", ""))]
            if used is not None:
                row.append(used.get(s.get("name", ""), "") if ph == "loaded" else "")
            row.append(f"{len(gaps)} gap(s), largest {1000 * float(s['stream'].get('largest_gap_s', 0)):.0f} ms"
                       if gaps else ("no gap" if "stream" in s else ""))
            rows.append(row)
    if not rows:
        return ["<p>No sweep was recorded.</p>"]
    head = ["phase", "sweep", "status", "samples recorded"] + (["samples used (primary)"] if used is not None else [])
    head.append("stream")
    if not any_stream:
        head, rows = head[:-1], [r[:-1] for r in rows]
    return [table(head, rows, left=(0, 1, 2, len(head) - 1) if any_stream else (0, 1, 2))]


def used_samples(manifest: dict, result: dict) -> dict[str, str]:
    """Samples the primary estimate used per loaded sweep; a leg of a combined up/down sweep shows the
    combined sweep's count (it was used, through the combination)."""
    samples = result.get("samples") or {}
    out = {}
    for s in ((manifest.get("phases") or {}).get("loaded") or {}).get("sweeps", []):
        name = str(s.get("name", ""))
        if name in samples:
            out[name] = str(samples[name])
        else:
            both = name.rsplit("-", 1)[0] + "-both"
            out[name] = f"{samples[both]} (combined up + down)" if both in samples else "not used"
    return out
