"""Malformed and dangerous robot YAML files are rejected by `plan` before any connection, naming file and key.

Each file in tests/yaml_corpus/ starts with ``# expect: <key> | <fragment of the message>``.
`plan` never connects without --connect, so a pass here means the refusal came first.
"""

from pathlib import Path

import pytest

from payload_agent import cli

CORPUS = sorted((Path(__file__).parent / "yaml_corpus").glob("*.yaml"))


def expectation(path: Path) -> tuple[str, str]:
    head = path.read_text(encoding="utf-8").splitlines()[0]
    key, _, fragment = head.removeprefix("# expect:").partition("|")
    return key.strip(), fragment.strip()


def test_the_corpus_is_large_enough():
    assert len(CORPUS) >= 40


@pytest.mark.parametrize("path", CORPUS, ids=[p.stem for p in CORPUS])
def test_plan_refuses_with_file_and_key(path, capsys):
    key, fragment = expectation(path)
    rc = cli.main(["plan", "--robot", str(path)])
    err = capsys.readouterr().err
    assert rc == 2, f"exit {rc}; stderr: {err}"
    assert path.name in err and key in err and fragment.lower() in err.lower(), err
    assert "Traceback" not in err
