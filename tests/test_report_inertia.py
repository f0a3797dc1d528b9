"""The report's inertia section (issue 21): tensor about the CoM with σ, the UR 6-vector, principal moments with
A/B/C, or the refusal and its reason; rendered in headless Chromium.

The run is the synthetic one of test_report (recorded, analysed by the agent); its result gets the inertia part
as the analysis writes it (``InertiaResult.to_json`` and ``payload_forms``), for a tensor the test sets.
"""

from __future__ import annotations

import html
import json
import re
import shutil

import numpy as np
import pytest

from payload_agent.evaluation.wrist_inertia import InertiaResult, support_problem
from payload_agent.output.payload_forms import payload_forms
from test_report import _has, _n_colours, _screenshot, cfg, make_run  # noqa: F401  (cfg: the module fixture)

pytest.importorskip("matplotlib")

from payload_agent.output.report import write_report  # noqa: E402

TENSOR = np.array([[0.030, -0.004, 0.003], [-0.004, 0.040, 0.005], [0.003, 0.005, 0.025]])
STD = np.full((3, 3), 0.0012) + np.diag([0.0008, 0.0011, 0.0005])


def _with_inertia(run_dir, tensor, std, truth=None):
    """Add the inertia part to the run's result.json (as evaluation.pipeline does) and write the report."""
    result = json.loads((run_dir / "result.json").read_text())
    res = InertiaResult(tensor, std, support_problem(tensor, std), None, ("w1-c-j6-fwd", "w1-c-j6-back"), 1.7, 4321)
    result.update(res.to_json())
    result["forms"] = payload_forms(result["mass_kg"], np.asarray(result["cog_mm"]) / 1000.0, res.inertia_com_kgm2)
    (run_dir / "result.json").write_text(json.dumps(result))
    if truth is not None:
        manifest = json.loads((run_dir / "manifest.json").read_text())
        manifest["simulation_truth"]["inertia_com_kgm2"] = truth.tolist()
        (run_dir / "manifest.json").write_text(json.dumps(manifest))
    return res, result


def _text(page: str) -> str:
    return html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page)))


@pytest.fixture(scope="module")
def base_run(cfg, tmp_path_factory):  # noqa: F811
    """One recorded and analysed run; each test's run is a copy of it (recording and analysis run once)."""
    return make_run(tmp_path_factory.mktemp("inertia_base"), cfg)


def _copy(run_dir, to):
    return shutil.copytree(run_dir, to / "runs" / run_dir.name)


@pytest.fixture(scope="module")
def given(cfg, base_run, tmp_path_factory):  # noqa: F811
    run = _copy(base_run, tmp_path_factory.mktemp("inertia"))
    res, result = _with_inertia(run, TENSOR, STD, truth=TENSOR * 1.02)
    assert res.refused is None
    return write_report(run, cfg), result


@pytest.fixture(scope="module")
def refused(cfg, base_run, tmp_path_factory):  # noqa: F811
    run = _copy(base_run, tmp_path_factory.mktemp("inertia_refused"))
    res, result = _with_inertia(run, TENSOR * 0.05, STD)  # a light, compact tool: σ far above 25 % of λmax
    assert res.refused
    return write_report(run, cfg), res.refused


def test_the_report_shows_the_tensor_with_sigma_the_ur_vector_and_the_principal_moments(given):
    out, result = given
    text = _text(out.read_text(encoding="utf-8"))
    assert "Inertia" in text and "About the centre of mass, flange axes" in text
    for i in range(3):
        for j in range(3):  # each element with its 95 % interval, and its σ
            assert f"{TENSOR[i, j]:.5f} ± {1.96 * STD[i, j]:.5f}" in text
    assert f"σ x {STD[0, 0]:.5f} {STD[0, 1]:.5f} {STD[0, 2]:.5f}" in text
    assert f"simulation truth z {1.02 * TENSOR[2, 0]:.5f}" in text
    ur = result["forms"]["ur"]["inertia_kgm2"]
    assert ur == pytest.approx([0.030, 0.040, 0.025, -0.004, 0.003, 0.005])
    assert "[" + ", ".join(f"{v:.5f}" for v in ur) + "] kg·m²" in text
    pr = result["forms"]["principal"]
    assert "A, B, C = " + ", ".join(f"{v:.1f}" for v in pr["abc_deg"]) + " °" in text
    assert "J = [" + ", ".join(f"{v:.5f}" for v in pr["j_kgm2"]) + "] kg·m²" in text
    assert sorted(pr["j_kgm2"]) == pytest.approx(sorted(np.linalg.eigvalsh(TENSOR)))
    assert "From 2 recorded wrist moves, 4321 samples, condition number 1.7" in text
    assert "Inertia not given" not in text


def test_a_refused_inertia_says_so_and_why_and_shows_no_controller_form(refused):
    out, reason = refused
    text = _text(out.read_text(encoding="utf-8"))
    assert "Inertia not given" in text and _text(reason) in text
    assert "more than 20 % of the largest principal moment" in text
    assert "not supported, not to be used" in text and "set_target_payload / setTargetPayload" not in text


def test_a_result_without_the_inertia_part_has_no_inertia_section(cfg, base_run, tmp_path):  # noqa: F811
    run = _copy(base_run, tmp_path)
    assert "<h2>Inertia</h2>" not in write_report(run, cfg).read_text(encoding="utf-8")


def test_the_inertia_sections_render_in_headless_chromium(given, refused, chromium, tmp_path):
    px = _screenshot(chromium, given[0], tmp_path / "given.png")
    assert _n_colours(px) > 200, "the page did not render"
    assert not _has(px, (0xc0, 0x39, 0x2b)), "a red box on a run whose checks passed and whose inertia was given"
    px = _screenshot(chromium, refused[0], tmp_path / "refused.png")
    assert _has(px, (0xc0, 0x39, 0x2b)), "the refused inertia's red box is not drawn"
