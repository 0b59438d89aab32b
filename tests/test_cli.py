"""Command line: ``python -m skcath``."""

import re
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from sklearn.utils import Bunch

from skcath._cli import build_parser, format_table, main, summarize_benchmark


def _make_benchmark():
    """``skcath.datasets.make_benchmark``, or skip while it is not available."""
    try:
        from skcath.datasets import make_benchmark
    except ImportError as exc:
        pytest.skip(f"skcath.datasets.make_benchmark is not importable yet ({exc})")
    return make_benchmark


@pytest.mark.parametrize(
    "argv, message",
    [
        ([], "required: command"),
        (["frobnicate"], "invalid choice"),
        (["benchmark", "--mechanism", "spring"], "--mechanism: invalid choice"),
        (["benchmark", "--n-catheters", "0"], "--n-catheters: expected a positive integer"),
        (["benchmark", "--n-runs", "two"], "--n-runs: expected a positive integer"),
        (["benchmark", "--random-state", "-1"], "--random-state: expected a non-negative"),
        (["benchmark", "--bogus"], "unrecognized arguments: --bogus"),
    ],
)
def test_bad_arguments_exit_2_with_message(argv, message, capsys):
    with pytest.raises(SystemExit) as excinfo:
        main(argv)
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "error:" in err
    assert message in err


def test_module_entry_point_reports_usage_errors():
    result = subprocess.run(
        [sys.executable, "-m", "skcath", "benchmark", "--n-runs", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert "usage: python -m skcath benchmark" in result.stderr
    assert result.stdout == ""


def test_defaults():
    args = build_parser().parse_args(["benchmark"])
    assert args.mechanism == "play"
    assert (args.n_catheters, args.n_runs, args.random_state) == (4, 3, 0)
    assert args.data_home is None and args.no_cache is False


def _toy_bunch():
    """Two runs of a hand-made benchmark with known statistics."""
    rows = []
    for run, n_sweep, n_motion in (("r0", 3, 4), ("r1", 2, 5)):
        n = n_sweep + n_motion
        rows.append(
            pd.DataFrame(
                {
                    "catheter": "C1",
                    "setting": run.replace("r", "S"),
                    "run": run,
                    "t": np.arange(n) * 0.1,
                    "phase": ["sweep"] * n_sweep + ["motion"] * n_motion,
                    "q1": np.linspace(0, 30, n),
                    "q2": np.linspace(0, 40, n),
                    "tau1": np.linspace(-1, 2, n),
                    "tau2": np.linspace(0, 5, n),
                    "ref_x": np.nan,
                    "ref_y": np.nan,
                    "ref_z": np.nan,
                }
            )
        )
    X = pd.concat(rows, ignore_index=True)
    for column in ("catheter", "setting", "run", "phase"):
        X[column] = X[column].astype("category")
    y = np.zeros((len(X), 3))
    y[:, 0] = np.arange(len(X))  # x span 6 in r0 (rows 0-6), 6 in r1 (rows 7-13)
    y[:7, 2] = np.linspace(0, 10, 7)  # z span 10 in r0, 0 in r1
    y[3] = np.nan  # a dropout
    return Bunch(X=X, y=y, noise_floor=0.25, mechanism="play")


def test_summary_values():
    rows = dict(summarize_benchmark(_toy_bunch()))
    assert rows["runs"] == "2"
    assert rows["catheters"] == "1"
    assert rows["shaft settings (catheter x setting)"] == "2"
    assert rows["samples per run (min / median / max)"] == "7 / 7 / 7"
    assert rows["sweep samples per run (median)"] == "2.5"
    assert rows["motion samples per run (median)"] == "4.5"
    assert rows["tip span x / y / z (median over runs, mm)"] == "6.0 / 0.0 / 5.0"
    assert rows["max motor magnitude |q| (deg)"] == "50.0"
    assert rows["tau1 range (N mm)"] == "[-1, 2]"
    assert rows["tracker dropouts (samples)"] == "1"
    assert rows["sensor-noise floor (mm)"] == "0.250"


def test_format_table_aligns_values():
    table = format_table([("a", "1"), ("longer", "2")], title="T")
    lines = table.splitlines()
    assert lines[0] == "T"
    assert lines[2:] == ["a       1", "longer  2"]


def test_benchmark_prints_summary(tmp_path, capsys):
    _make_benchmark()
    argv = [
        "benchmark",
        "--n-catheters", "1",
        "--n-runs", "1",
        "--no-cache",
        "--data-home", str(tmp_path),
    ]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    for label in (
        "runs",
        "catheters",
        "samples per run (min / median / max)",
        "sweep samples per run (median)",
        "tip span x / y / z (median over runs, mm)",
        "max motor magnitude |q| (deg)",
        "tau1 range (N mm)",
        "tau2 range (N mm)",
        "sensor-noise floor (mm)",
        "generation time (s)",
    ):
        assert label in out
    assert re.search(r"^cache +disabled$", out, flags=re.M)
    assert re.search(r"^mechanism +play$", out, flags=re.M)
    # --no-cache must not write anything.
    assert list(tmp_path.iterdir()) == []


def test_benchmark_uses_the_cache(tmp_path, capsys):
    _make_benchmark()
    argv = ["benchmark", "--n-catheters", "1", "--n-runs", "1", "--data-home", str(tmp_path)]
    assert main(argv) == 0
    first = capsys.readouterr().out
    assert f"{tmp_path} (written)" in first
    assert "generation time (s)" in first
    assert any(tmp_path.iterdir())
    assert main(argv) == 0
    second = capsys.readouterr().out
    assert f"{tmp_path} (loaded)" in second
    assert "load time (s)" in second


def test_unusable_data_home_is_a_usage_error(tmp_path, capsys):
    _make_benchmark()
    not_a_folder = tmp_path / "file.txt"
    not_a_folder.write_text("x")
    with pytest.raises(SystemExit) as excinfo:
        main(["benchmark", "--n-catheters", "1", "--n-runs", "1", "--data-home", str(not_a_folder)])
    assert excinfo.value.code == 2
    assert "argument --data-home: cannot use it as the cache folder" in capsys.readouterr().err


def test_mechanism_choices_match_the_simulator():
    _make_benchmark()
    from skcath import _cli, datasets

    assert tuple(_cli.MECHANISMS) == tuple(datasets.MECHANISMS)
