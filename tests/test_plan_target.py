"""`plan --target-std G,MM` predicts candidate procedures' σ before moving and names the fastest that meets it."""

import json

from conftest import ROOT
from payload_agent import cli


def test_plan_for_a_target_picks_a_procedure_from_the_declared_noise(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "20,5", "--json"])
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert rc == 0 and doc["target"]["noise_source"].startswith("effort noise declared")
    chosen = doc["target"]["chosen"]
    assert chosen is not None and chosen["mass_std_g"] <= 20 and chosen["cog_std_mm"] <= 5
    assert "chosen:" in out.err


def test_a_malformed_target_names_the_option(capsys):
    rc = cli.main(["plan", "--robot", str(ROOT / "configs" / "sim-ec66.yaml"), "--target-std", "2mm"])
    assert rc == 2 and "--target-std" in capsys.readouterr().err
