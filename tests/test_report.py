"""HTML run report (payload_agent.output.report) on synthetic run folders written through the real recorder:
a passed run, a run whose quality checks failed, and a run the supervision stopped mid-sweep."""

from __future__ import annotations

import base64
import html
import json
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.recording import history
from payload_agent.configuration.config import parse_config
from payload_agent.types import Sample
from payload_agent.errors import DataError
from payload_agent.recording.history import HistoryEntry
from payload_agent.motion.planner import make_plan
from payload_agent.recording.recorder import RunRecorder
from payload_agent.evaluation.pipeline import analyse_run as analyse

pytest.importorskip("matplotlib")

from payload_agent.output.report import write_report  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TRUTH = (2.0, (40.0, -25.0, 70.0))  # kg, mm
ARM = np.array([6.0, 1.2, 0.4, 0.6])  # a fake "arm gravity" θ: the empty flange is not free of load
DT = 0.03  # 33 Hz samples: enough for the segmenter, few regressor evaluations


def _profile(q0: np.ndarray, q1: np.ndarray, v: float, a: float) -> np.ndarray:
    """Angles of a synchronized trapezoidal PTP move sampled every DT, with standstill either side."""
    d = float(np.max(np.abs(q1 - q0)))
    if d == 0:
        return np.array([q0] * 5)
    if d < v * v / a:
        v = math.sqrt(d * a)
    t_acc, dur = v / a, d / v + v / a
    t = np.arange(0.0, dur + DT, DT)
    s = np.where(t < t_acc, 0.5 * a * t ** 2,
                 np.where(t < dur - t_acc, 0.5 * a * t_acc ** 2 + v * (t - t_acc), d - 0.5 * a * np.clip(dur - t, 0, None) ** 2))
    s = np.clip(s, 0, d) / d
    path = q0 + s[:, None] * (q1 - q0)
    return np.vstack([[q0] * 10, path, [q1] * 10])


_REGRESSORS: dict[int, tuple[object, dict[bytes, np.ndarray]]] = {}


def _regressor(kin, q: np.ndarray) -> np.ndarray:
    """The payload regressor of kinematics ``kin`` at q, computed once per angle set: the synthetic runs
    walk the same plan's paths in both phases and in each run (the kinematics object is held, so its id
    stays its own)."""
    _, table = _REGRESSORS.setdefault(id(kin), (kin, {}))
    key = np.asarray(q, float).tobytes()
    if key not in table:
        table[key] = kin.payload_regressor(q, range(6))
    return table[key]


def make_run(tmp_path: Path, cfg, *, name: str = "20261121-080000-sim-ec66", gain_error: float = 1.0,
             stop_after: int | None = None) -> Path:
    """A recorded run (empty + loaded phase) as `payload-agent run` writes it, then analysed.

    ``gain_error``: joint 3 of the loaded run reads this factor too much effort (a drive-gain
    mistake the quality checks must catch). ``stop_after``: the loaded phase stops in the middle of
    its sweep number ``stop_after`` (0-based) as a supervision trip leaves it: no result.
    """
    rng = np.random.default_rng(7)
    kin = cfg.robot.kinematics
    gains = np.asarray(cfg.effort.gains_nm_per_unit, float)
    theta = np.array([TRUTH[0], *(TRUTH[0] * np.asarray(TRUTH[1]) / 1000.0)])
    plan = make_plan(cfg)
    run_dir = tmp_path / "runs" / name
    rec = RunRecorder(run_dir, {"format": "payload-agent-run/1", "software_version": "test", "robot": cfg.robot.name,
                                "config": json.loads(json.dumps(cfg.raw)),
                                "controller": {"vendor": "Elite Robots", "model": "EC66", "firmware": "t"},
                                "effort_unit": "percent_rated", "gains_nm_per_unit": list(gains),
                                "procedure": plan.procedure.name, "plan_fingerprint": plan.fingerprint(),
                                "plan": [m.to_json() for m in plan.moves],
                                "simulation_truth": {"mass_kg": TRUTH[0], "cog_mm": list(TRUTH[1])}})
    t = 0.0
    scale = np.ones(6)
    for phase, payload in (("empty", np.zeros(4)), ("loaded", theta)):
        rec.begin_phase(phase)
        if phase == "loaded":
            scale[2] = gain_error
        q = np.radians(cfg.simulation.start_deg)
        n_sweep = 0
        for move in plan.moves:
            path = _profile(q, np.asarray(move.target_rad), move.speed_rad_s, move.accel_rad_s2)
            if move.sweep is not None:
                stopping = phase == "loaded" and stop_after is not None and n_sweep == stop_after
                rec.begin_sweep(move)
                for qi in (path[: len(path) // 2] if stopping else path):
                    Y = _regressor(kin, qi)
                    tau = Y @ (ARM + payload) * scale + rng.normal(0, 0.05, 6)
                    rec.sink(Sample(t, t, tuple(map(float, qi)), tuple(map(float, tau / gains))))
                    t += DT
                if stopping:
                    reason = "the sample stream stalled: no sample for 212 ms (limit 50 ms)"
                    stop = {"reason": reason, "stop_delay_s": 0.004, "acknowledged": True, "via": "command channel",
                            "attempts": 1}
                    rec.end_sweep("aborted")
                    rec.end_phase(f"aborted: SupervisionTrip: motion stopped by the supervision: {reason}")
                    rec.update(status="incomplete", stop=stop,
                               stopped_because=f"SupervisionTrip: motion stopped by the supervision: {reason}; stop "
                                               "sent over the command channel 4 ms later, acknowledged")
                    return run_dir
                rec.end_sweep("complete")
                n_sweep += 1
            q = path[-1]
        rec.end_phase("complete")
    analyse(cfg, run_dir).write(run_dir / "result.json")  # as `run` and `solve` leave it
    return run_dir


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    data = yaml.safe_load((ROOT / "configs" / "sim-ec66.yaml").read_text())
    data = tweak(data, "procedure.speed_percent", 10)
    state = tmp_path_factory.mktemp("state")  # no calibration from the working tree's state/ folder
    return parse_config(tweak(tweak(data, "storage.state_dir", str(state)), "storage.runs_dir", str(state / "runs")))


@pytest.fixture(scope="module")
def run_dir(cfg, tmp_path_factory):
    return make_run(tmp_path_factory.mktemp("report"), cfg)


def _n_sweep_figures(cfg) -> int:
    return len({(m.sweep.pose, m.sweep.joint) for m in make_plan(cfg).sweeps})


class _Collect(HTMLParser):
    def __init__(self):
        super().__init__()
        self.imgs: list[str] = []
        self.stack: list[str] = []
        self.errors: list[str] = []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.imgs.append(dict(attrs).get("src", ""))
        elif tag not in ("meta", "br", "link"):
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes <{self.stack[-1] if self.stack else None}>")
        else:
            self.stack.pop()


@pytest.fixture(scope="module")
def report_with_history(run_dir, cfg, tmp_path_factory):
    """The run's report with a three-entry history (two older results and this run's)."""
    import json

    db = tmp_path_factory.mktemp("state") / "history.sqlite"
    result = json.loads((run_dir / "result.json").read_text())
    for i, mass in enumerate([1.99, 2.0]):
        e = HistoryEntry.from_result_json(result, tool="gripper-A", time_utc=f"2026-11-{10 + i}T08:00:00+00:00")
        e.mass_kg, e.run_dir = mass, f"runs/old{i}"
        history.record(db, e)
    history.record(db, HistoryEntry.from_result_json(result, tool="gripper-A"))
    return write_report(run_dir, cfg, history_db=db), result


def test_report_is_self_contained_html_with_png_plots(report_with_history, run_dir, cfg):
    out, result = report_with_history
    assert out == run_dir / "report.html"
    text = out.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    parser = _Collect()
    parser.feed(text)
    assert parser.errors == [] and parser.stack == []  # every tag closed, properly nested
    # one figure per sweep (both directions together) + residuals + history trend, each an inline PNG
    assert len(parser.imgs) == _n_sweep_figures(cfg) + 2
    for src in parser.imgs:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1]).startswith(PNG_SIGNATURE)
    assert f"{result['mass_kg']:.4f}" in text  # the primary mass in the header
    assert "simulation truth" in text and "mass pose b vs pose d" in text and "gripper-A" in text
    assert "<script" not in text and "http://" not in text and "https://" not in text  # nothing external
    # the general estimate is close to the synthetic truth: the plotted model is the right one
    assert result["estimates"]["general"]["mass_kg"] == pytest.approx(TRUTH[0], abs=0.02)


@pytest.fixture(scope="module")
def failed_report(cfg, tmp_path_factory) -> tuple[Path, str]:
    """A run whose quality checks fail (15 % gain error on joint 3), recorded through the UR driver and
    applied anyway by hand: its report page (written once for several tests)."""
    run = make_run(tmp_path_factory.mktemp("failed"), cfg, name="20261121-090000-sim-ec66", gain_error=1.15)
    result = json.loads((run / "result.json").read_text())
    m_json = json.loads((run / "manifest.json").read_text())
    m_json["config"]["driver"] = {"type": "ur_rtde", "host": "127.0.0.1"}
    m_json["payload_write"] = {"requested": True, "applied": True, "reason": None,
                               "written": {"mass_kg": result["mass_kg"], "cog_mm": result["cog_mm"], "tool_num": None},
                               "read_back": {"mass_kg": round(result["mass_kg"], 3), "cog_mm": result["cog_mm"],
                                             "tool_num": None}}
    (run / "manifest.json").write_text(json.dumps(m_json))
    out = write_report(run, cfg, out_path=run / "sub" / "r.html")  # a custom path, no history
    assert out == run / "sub" / "r.html" and not (run / "report.html").exists()
    return run, out.read_text()


@pytest.fixture(scope="module")
def stopped_report(cfg, tmp_path_factory) -> tuple[Path, str]:
    run = make_run(tmp_path_factory.mktemp("stopped"), cfg, name="20261121-100000-sim-ec66", stop_after=2)
    return run, write_report(run, cfg).read_text()


def _text(html_text: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html_text)).replace("&#x27;", "'")


def test_report_shows_the_values_for_the_controller_and_the_write_back(report_with_history, failed_report):
    out, result = report_with_history
    text = _text(out.read_text())
    m = result["mass_kg"]
    assert f"Values for the Elite EC controller (tool flange frame; Elite pendant: tool payload): mass {m:.3f} kg" in text
    assert f"centre of gravity X {result['cog_mm'][0]:.1f} mm, Y {result['cog_mm'][1]:.1f} mm" in text
    assert f'cmd_set_payload {{"tool_num": 0, "m": {m:.3f}, "cog": [{result["cog_mm"][0]:.1f}, ' in html.unescape(text)
    assert "Not written to the controller" in text
    # recorded through the UR driver: PolyScope's screen in kg and mm, URScript in metres; written and read back
    run, page = failed_report
    result = json.loads((run / "result.json").read_text())
    text = _text(page)
    m, (x, y, z) = result["mass_kg"], result["cog_mm"]
    assert f"mass {m:.3f} kg, centre of gravity X {x:.1f} mm, Y {y:.1f} mm, Z {z:.1f} mm" in text
    assert "Values for the Universal Robots controller (tool flange frame; PolyScope" in text
    assert f"URScript form: set_target_payload({m:.3f}, [{x / 1000:.4f}, {y / 1000:.4f}, {z / 1000:.4f}])" in text
    assert f"Written to the controller and read back: {m:.3f} kg" in text


def test_failed_run_report_names_the_failed_check_and_by_how_much(failed_report):
    run, page = failed_report
    result = json.loads((run / "result.json").read_text())
    failed = [c for c in result["quality"]["checks"] if not c["passed"]]
    assert failed, "a 15 % gain error on joint 3 must fail a quality check"
    text = _text(page)
    assert "quality checks FAILED" in text and "do not type these values into the controller" in text
    rows = re.findall(r'<tr class="failed">(.*?)</tr>', page, flags=re.S)
    assert len(rows) == len(failed)
    for c, row in zip(failed, rows):
        cells = [_text(x).strip() for x in re.findall(r"<td[^>]*>(.*?)</td>", row, flags=re.S)]
        assert cells[0] == c["check"] and cells[1] == "FAILED"
        minimum = c["check"].startswith(("mass significance", "samples"))
        over = (c["limit"] - c["value"]) if minimum else (c["value"] - c["limit"])
        assert cells[4].startswith("exceeds the limit by" if not minimum else "short of the limit by")
        assert f"({100 * over / abs(c['limit']):.0f} %)" in cells[4]
    assert "<h2>History</h2>" not in page  # written without a history database
    # passed checks follow, with units (σ, kg, × noise, samples)
    assert "≤ 3.00 σ" in text and "≤ 50.000 kg" in text and "samples" in text


def test_stopped_run_gets_a_report_of_what_was_recorded_and_why(stopped_report):
    stopped_run, page = stopped_report
    assert not (stopped_run / "result.json").exists()
    text = _text(page)
    assert "Payload identification stopped" in text and "run did not finish" in text
    assert "the sample stream stalled: no sample for 212 ms" in text
    assert "SupervisionTrip" not in text and "supervision trip: motion stopped" in text  # a sentence, no class name
    assert "acknowledged by the controller" in text and "4 ms after the fault" in text
    manifest = json.loads((stopped_run / "manifest.json").read_text())
    sweeps = manifest["phases"]["loaded"]["sweeps"]
    assert [s["status"] for s in sweeps] == ["complete", "complete", "aborted"]
    for s in sweeps:
        assert s["name"] in text
    total = sum(s["samples"] for ph in manifest["phases"].values() for s in ph["sweeps"])
    assert f"{total} samples were recorded" in text
    parser = _Collect()
    parser.feed(page)
    assert parser.errors == [] and len(parser.imgs) >= 2  # the recorded traces, the cut sweep included
    assert "aborted" in text


def test_report_errors(run_dir, cfg, tmp_path):
    with pytest.raises(DataError, match="manifest.json is missing"):
        write_report(tmp_path, cfg)
    with pytest.raises(DataError, match="not a folder"):
        write_report(tmp_path / "nothing", cfg)


def _screenshot(chromium, html: Path, shot: Path, height: int = 2400) -> np.ndarray:
    """The page as a 1200 x ``height`` window shows it, in the session's headless Chromium (conftest)."""
    from matplotlib.image import imread

    shot.write_bytes(chromium.screenshot(html.as_uri(), 1200, height))
    img = imread(shot)[..., :3]
    assert img.shape[:2] == (height, 1200)
    return (img * 255).astype(int).reshape(-1, 3)


def _n_colours(px: np.ndarray) -> int:
    """How many distinct colours the screenshot holds (RGB packed into one integer: a 1-D unique, not a
    row-wise one over millions of pixels)."""
    return len(np.unique((px[:, 0] << 16) | (px[:, 1] << 8) | px[:, 2]))


def _has(px: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> bool:
    return bool(np.any(np.all(np.abs(px - rgb) < tol, axis=1)))


def test_failed_and_stopped_reports_render_in_headless_chromium(failed_report, stopped_report, chromium,
                                                                tmp_path):
    for page in (failed_report[0] / "sub" / "r.html", stopped_report[0] / "report.html"):
        px = _screenshot(chromium, page, tmp_path / f"{page.parent.name}.png")
        assert _n_colours(px) > 200, f"{page}: the page did not render"
        assert _has(px, (0xc0, 0x39, 0x2b)), f"{page}: no red FAILED badge / stop box"
        assert _has(px, (0x1f, 0x5f, 0xa8)), f"{page}: the recorded traces are not drawn"


def test_report_renders_in_headless_chromium(report_with_history, chromium, tmp_path):
    out, _ = report_with_history
    px = _screenshot(chromium, out, tmp_path / "shot.png")
    assert _n_colours(px) > 200, "the screenshot is nearly uniform: the page did not render"
    # the plots are drawn: the model's orange, the loaded sweep's blue and the empty flange's down leg (its own
    # colour now, not the up leg's grey) appear on the page
    from payload_agent.output.report_plots import COLORS

    rgb = lambda hex_: tuple(int(hex_[i:i + 2], 16) for i in (1, 3, 5))
    assert _has(px, rgb(COLORS["model"])) and _has(px, rgb(COLORS["loaded"]))
    assert COLORS["empty"] != COLORS["empty_down"] and _has(px, rgb(COLORS["empty_down"]), tol=6)
