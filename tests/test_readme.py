"""The README and ``docs/api.md`` say what the code does: their Python blocks run as a user
would run them and print what they claim, the estimator table is the registry, and the
quick-start test command is the one CI runs."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import attopt

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()


def python_blocks(text: str) -> list[str]:
    """The fenced ``python`` code blocks of a markdown text, in order."""
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.MULTILINE | re.DOTALL)


API_BLOCKS = python_blocks((ROOT / "docs" / "api.md").read_text())


def run_block(block: str, cwd: Path) -> str:
    """Run ``block`` in a fresh interpreter in ``cwd``; its standard output."""
    done = subprocess.run(
        [sys.executable, "-c", block],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_the_documents_have_their_examples() -> None:
    assert len(python_blocks(README)) == 2
    assert len(API_BLOCKS) == 2


@pytest.mark.parametrize("block", API_BLOCKS, ids=["results", "options"])
def test_api_block_runs(block: str, tmp_path: Path) -> None:
    output = run_block(block, tmp_path)
    assert "Solution('quest'" in output or "SdpOptions(solver='SCS'" in output, output


def test_readme_snapshot_example_solves_with_every_vector_estimator(tmp_path: Path) -> None:
    snapshot_block = next(b for b in python_blocks(README) if "Snapshot.from_vectors" in b)
    output = run_block(snapshot_block, tmp_path)
    solved = re.findall(r"^Solution\('(\w+)', yaw/pitch/roll", output, flags=re.MULTILINE)
    assert solved == attopt.estimators("snapshot", accepts=attopt.VectorMeasurement)
    errors = re.search(r"^0 +(\S+) +(\S+) +(\S+)$", output, flags=re.MULTILINE)
    bound = re.search(r"CRB sigma \(deg\): \[([^\]]*)\]", output)
    assert errors is not None and bound is not None, output
    sigma = [float(s) for s in bound.group(1).split()]
    assert all(abs(float(e)) < 4.0 * s for e, s in zip(errors.groups(), sigma, strict=True))


def test_readme_pass_example_tracks_every_epoch_within_its_noise(tmp_path: Path) -> None:
    pass_block = next(b for b in python_blocks(README) if "run_estimators" in b)
    output = run_block(pass_block, tmp_path)
    rows = re.findall(
        r"^Track\('(\w+)', (\d+) epochs, (\d+) valid.*RMS \(deg\): \[([^\]]*)\]$",
        output,
        flags=re.MULTILINE,
    )
    assert [row[0] for row in rows] == ["mekf", "rts", "fg_batch"], output
    for _, epochs, valid, rms in rows:
        assert epochs == valid == "301"
        assert max(float(x) for x in rms.split(",")) < 0.2


def estimator_table() -> list[str]:
    """The README's estimator table rows, generated from the registry."""
    return [
        f"| `{name}` | {e.kind} | {', '.join(f'`{a.__name__}`' for a in e.accepts)} "
        f"| {e.description} |"
        for name, e in attopt.ESTIMATORS.items()
    ]


def test_readme_estimator_table_is_the_registry() -> None:
    header = "| name | kind | accepts | method (paper, equations) |\n|---|---|---|---|\n"
    start = README.index(header) + len(header)
    rows = README[start:].split("\n\n", 1)[0].splitlines()
    assert rows == estimator_table(), "\n".join(estimator_table())


def test_readme_quick_start_test_command_is_what_ci_runs() -> None:
    commands = re.findall(r"^```\n(python3 -m venv .*)\n```$", README, flags=re.MULTILINE)
    assert [c.rsplit("&& ", 1)[1] for c in commands] == [
        ".venv/bin/attopt run wahba-mag-sun",
        ".venv/bin/python -m pytest -q",
    ]
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
