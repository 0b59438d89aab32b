"""The commands documented in README.md are the ones CI and users run.

``.ci/run`` executes the README's test command; these checks keep the two
from drifting apart, make sure the documented main-job command parses, and
run the README's Python examples against the current API.
"""

import re
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CI_RUN = ROOT / ".ci" / "run"

FRESH_VENV = "python3 -m venv .venv && "


def _code_lines(text):
    """Non-empty lines inside fenced code blocks of a Markdown text."""
    blocks = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.M | re.S)
    return [line.strip() for block in blocks for line in block.splitlines() if line.strip()]


def _commands(marker):
    """README code lines that set up a fresh environment and contain ``marker``."""
    lines = _code_lines(README.read_text(encoding="utf-8"))
    return [line for line in lines if line.startswith(FRESH_VENV) and marker in line]


def _ci_lines():
    text = CI_RUN.read_text(encoding="utf-8")
    return [line.strip() for line in text.splitlines()]


def _ci_commands():
    """Lines of .ci/run that are neither blank nor comments."""
    return [line for line in _ci_lines() if line and not line.startswith("#")]


def test_readme_has_one_test_command():
    found = _commands("-m pytest")
    assert len(found) == 1, f"expected one fresh-machine test command in README.md, got {found}"
    command = found[0]
    assert '-c constraints.txt -e ".[test]"' in command
    assert command.endswith(".venv/bin/python -m pytest -q")


def test_ci_runs_exactly_the_readme_test_command():
    (command,) = _commands("-m pytest")
    assert command in _ci_lines(), ".ci/run must contain the README test command verbatim"
    # Under `set -e` the status of an `a && b && c` chain only ends the script
    # when it is the last command, so it must come last.
    assert _ci_commands()[-1] == command


def test_ci_script_is_strict():
    assert CI_RUN.read_text(encoding="utf-8").startswith("#!/usr/bin/env bash\n")
    assert "set -euo pipefail" in _ci_commands()


def test_readme_main_job_command_parses():
    found = _commands("-m skcath reproduce")
    assert len(found) == 1, f"expected one fresh-machine main-job command in README.md, got {found}"
    command = found[0]
    # matplotlib (the `plot` extra) draws the figures the command writes.
    assert '-c constraints.txt -e ".[plot]"' in command
    # The arguments after `-m skcath` must be accepted by the command line:
    # the quick form of the paper's protocol.
    from skcath._cli import build_parser

    words = shlex.split(command.split("&&")[-1])
    args = build_parser().parse_args(words[words.index("skcath") + 1 :])
    assert args.command == "reproduce"
    assert args.quick


def test_readme_documents_docs_build():
    text = README.read_text(encoding="utf-8")
    assert '-e ".[docs]"' in text
    assert "-m sphinx -b html docs docs/_build/html" in text
    assert (ROOT / "docs" / "conf.py").is_file()


@pytest.mark.parametrize("name", ["constraints.txt", "LICENSE", "docs/data_format.rst"])
def test_files_named_in_readme_exist(name):
    assert name in README.read_text(encoding="utf-8")
    assert (ROOT / name).is_file()


def _python_blocks():
    text = README.read_text(encoding="utf-8")
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)


def _block_using(name):
    found = [block for block in _python_blocks() if name in block]
    assert found, f"README.md has no Python example using {name}"
    return found[0]


def test_readme_benchmark_example_runs(tmp_path, monkeypatch, capsys):
    import skcath
    import skcath.datasets

    if not hasattr(skcath.datasets, "make_benchmark"):
        pytest.skip("skcath.datasets.make_benchmark is not available yet")

    if not hasattr(skcath, "check_recordings"):
        pytest.skip("skcath.check_recordings is not exported yet")
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "data"))
    namespace = {}
    exec(compile(_block_using("make_benchmark"), "README.md", "exec"), namespace)
    # The tip computed from the raw poses is the noisy target of the data set.
    finite = np.isfinite(namespace["y"]).all(axis=1)
    np.testing.assert_allclose(namespace["p"][finite], namespace["y"][finite], atol=1e-6)
    padded = namespace["padded"]
    assert padded.values.shape[0] == padded.mask.shape[0] == len(namespace["data"].runs)


def test_readme_read_recording_example_runs(tmp_path, monkeypatch):
    n = 4400
    rng = np.random.default_rng(0)
    base_q = Rotation.random(n, random_state=1).as_quat()  # scalar last
    frame = pd.DataFrame(
        {
            "motor_ap_deg": rng.normal(size=n),
            "motor_lr_deg": rng.normal(size=n),
            "torque_ap": rng.normal(size=n),
            "torque_lr": rng.normal(size=n),
            "tip_x": rng.normal(size=n),
            "tip_y": rng.normal(size=n),
            "tip_z": 60.0 + rng.normal(size=n),
            "base_x": 1.0,
            "base_y": 2.0,
            "base_z": 3.0,
            "base_rx": base_q[:, 0],
            "base_ry": base_q[:, 1],
            "base_rz": base_q[:, 2],
            "base_rw": base_q[:, 3],
        }
    )
    monkeypatch.chdir(tmp_path)
    frame.to_csv("C1_S3_r1.csv", index=False)
    namespace = {}
    exec(compile(_block_using("read_recording"), "README.md", "exec"), namespace)
    X, y = namespace["X"], namespace["y"]
    assert len(X) == n and y.shape == (n, 3)
    assert (X["phase"] == "sweep").sum() == 4320
    expected = Rotation.from_quat(base_q).inv().apply(
        frame[["tip_x", "tip_y", "tip_z"]].to_numpy() - [1.0, 2.0, 3.0]
    )
    np.testing.assert_allclose(y, expected, atol=1e-9)


def test_readme_backbone_example_runs(tmp_path, monkeypatch, capsys):
    """The Pipeline / cross_validate example of the README runs and scores in mm."""
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "data"))
    namespace = {}
    exec(compile(_block_using("cross_validate"), "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    match = re.search(r"PDL: ([0-9.]+) mm", out)
    assert match, out
    assert 0.5 < float(match.group(1)) < 30.0


def test_readme_residual_example_runs(tmp_path, monkeypatch, capsys):
    """The residual example trains, predicts, and beats its backbone on held-out settings."""
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "data"))
    namespace = {}
    exec(compile(_block_using("GRUResidual"), "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    match = re.search(r"PDL ([0-9.]+) mm, PDL\+GRU ([0-9.]+) mm", out)
    assert match, out
    pdl, gru = float(match.group(1)), float(match.group(2))
    assert 0.5 < gru < pdl < 30.0
