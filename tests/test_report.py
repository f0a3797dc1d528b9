"""HTML run report (agent/report.py) on a synthetic run folder written through the real recorder."""

from __future__ import annotations

import base64
import math
import re
import shutil
import subprocess
import tempfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.output import history
from payload_agent.configuration.config import parse_config
from payload_agent.types import Sample
from payload_agent.errors import DataError
from payload_agent.output.history import HistoryEntry
from payload_agent.motion.planner import make_plan
from payload_agent.recording.recorder import RunRecorder
try:  # the analysis entry point is moving from runner to analysis (refactor in progress)
    from payload_agent.evaluation.pipeline import analyse_run as analyse
except ImportError:
    from payload_agent.session.runner import analyse

pytest.importorskip("matplotlib")

from payload_agent.output.report import write_report  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TRUTH = (2.0, (40.0, -25.0, 70.0))  # kg, mm
ARM = np.array([6.0, 1.2, 0.4, 0.6])  # a fake "arm gravity" θ: the empty flange is not free of load
DT = 0.03  # 33 Hz samples: enough for the segmenter, few regressor evaluations
CHROMIUM = Path("/usr/bin/chromium")


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


def make_run(tmp_path: Path, cfg) -> Path:
    """A recorded run (empty + loaded phase) as `payload-agent run` writes it, then analysed."""
    rng = np.random.default_rng(7)
    kin = cfg.robot.kinematics
    gains = np.asarray(cfg.effort.gains_nm_per_unit, float)
    theta = np.array([TRUTH[0], *(TRUTH[0] * np.asarray(TRUTH[1]) / 1000.0)])
    plan = make_plan(cfg)
    run_dir = tmp_path / "runs" / "20261121-080000-sim-ec66"
    rec = RunRecorder(run_dir, {"format": "payload-agent-run/1", "software_version": "test", "robot": cfg.robot.name,
                                "config": {}, "controller": {"vendor": "Elite Robots", "model": "EC66", "firmware": "t"},
                                "effort_unit": "percent_rated", "gains_nm_per_unit": list(gains),
                                "procedure": plan.procedure.name, "plan_fingerprint": plan.fingerprint(),
                                "plan": [m.to_json() for m in plan.moves],
                                "simulation_truth": {"mass_kg": TRUTH[0], "cog_mm": list(TRUTH[1])}})
    t = 0.0
    for phase, payload in (("empty", np.zeros(4)), ("loaded", theta)):
        rec.begin_phase(phase)
        q = np.radians(cfg.simulation.start_deg)
        for move in plan.moves:
            path = _profile(q, np.asarray(move.target_rad), move.speed_rad_s, move.accel_rad_s2)
            if move.sweep is not None:
                rec.begin_sweep(move)
                for qi in path:
                    Y = kin.payload_regressor(qi, range(6))
                    tau = Y @ (ARM + payload) + rng.normal(0, 0.05, 6)
                    rec.sink(Sample(t, t, tuple(map(float, qi)), tuple(map(float, tau / gains))))
                    t += DT
                rec.end_sweep("complete")
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


def test_report_without_history_and_custom_path(run_dir, cfg, tmp_path):
    out = write_report(run_dir, cfg, out_path=tmp_path / "sub" / "r.html")
    assert out == tmp_path / "sub" / "r.html"
    text = out.read_text(encoding="utf-8")
    assert len(re.findall(r'<img [^>]*src="data:image/png;base64,', text)) == _n_sweep_figures(cfg) + 1
    assert "<h2>History</h2>" not in text


def test_report_refuses_a_run_without_result(run_dir, cfg, tmp_path):
    bare = tmp_path / "bare"
    shutil.copytree(run_dir, bare)
    (bare / "result.json").unlink()
    with pytest.raises(DataError, match="no result.json.*payload-agent solve"):
        write_report(bare, cfg)
    with pytest.raises(DataError, match="manifest.json is missing"):
        write_report(tmp_path, cfg)


@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed (apt-get install chromium)")
def test_report_renders_in_headless_chromium(report_with_history, tmp_path):
    from matplotlib.image import imread

    out, _ = report_with_history
    shot = tmp_path / "shot.png"
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.run([str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                               "--no-first-run", "--disable-background-networking", "--disable-component-update",
                               "--disable-sync", f"--user-data-dir={profile}", f"--screenshot={shot}",
                               "--window-size=1200,2400", out.as_uri()], capture_output=True, timeout=120)
    assert shot.exists(), f"chromium wrote no screenshot: {proc.stderr.decode(errors='replace')[-2000:]}"
    img = imread(shot)[..., :3]
    assert img.shape[:2] == (2400, 1200)
    colours = np.unique((img * 255).astype(np.uint8).reshape(-1, 3), axis=0)
    assert len(colours) > 200, "the screenshot is nearly uniform: the page did not render"
    # the plots are drawn: the model's orange and the loaded sweep's blue appear on the page
    px = (img * 255).astype(int).reshape(-1, 3)
    assert np.any(np.all(np.abs(px - [0xe0, 0x7b, 0x00]) < 12, axis=1))
    assert np.any(np.all(np.abs(px - [0x1f, 0x5f, 0xa8]) < 12, axis=1))
