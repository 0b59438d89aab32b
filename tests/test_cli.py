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


# ---------------------------------------------------------------------------
# reproduce
# ---------------------------------------------------------------------------
#: Settings of the small data set the ``reproduce`` tests run on (per catheter).
REPRODUCE_SETTINGS = ("S00", "S01", "S02", "S03", "S04")


def _tiny_schedule(name="tiny"):
    from skcath.protocol import Schedule

    return Schedule(
        name=name,
        seeds=(0,),
        n_setting_folds=2,
        variants=("PDL+GRU",),
        model_params={"module__hidden_size": 8, "window_step_s": 20.0},
        pretrain_params={"max_epochs": 1},
        finetune_params={"max_epochs": 1},
    )


@pytest.fixture(scope="module")
def reproduce_data(tmp_path_factory):
    """A long-format CSV of two catheters (settings S00-S04), with the frames it was written from."""
    make_benchmark = _make_benchmark()
    bench = make_benchmark(n_catheters=2, n_runs=1)
    keep = bench.X["setting"].astype(str).isin(REPRODUCE_SETTINGS).to_numpy()
    X = bench.X[keep].reset_index(drop=True)
    y = np.asarray(bench.y, dtype=float)[keep]
    frame = X.copy()
    for k, axis in enumerate("xyz"):
        frame[f"p_{axis}"] = y[:, k]
    path = tmp_path_factory.mktemp("reproduce") / "recordings.csv"
    frame.to_csv(path, index=False)
    return path, X, y


class _Stop(Exception):
    """Raised by the run_protocol spy once the arguments are recorded."""


@pytest.fixture
def protocol_spy(monkeypatch):
    """Record the arguments ``reproduce`` passes to run_protocol, then stop."""
    from skcath import protocol

    calls = []

    def spy(X, y, **kwargs):
        calls.append({"X": X, "y": y, **kwargs})
        raise _Stop

    monkeypatch.setattr(protocol, "run_protocol", spy)
    return calls


def test_reproduce_csv_round_trips(reproduce_data):
    from skcath.io import read_recording

    path, X, y = reproduce_data
    X_read, y_read = read_recording(path)
    assert list(X_read.columns) == [
        "catheter", "setting", "run", "t", "phase", "q1", "q2", "tau1", "tau2", "ref_x", "ref_y", "ref_z",
    ]
    for column in ("catheter", "setting", "run", "phase"):
        np.testing.assert_array_equal(X_read[column].astype(str).to_numpy(), X[column].astype(str).to_numpy())
    numeric = ["t", "q1", "q2", "tau1", "tau2", "ref_x", "ref_y", "ref_z"]
    np.testing.assert_allclose(X_read[numeric].to_numpy(), X[numeric].to_numpy(), rtol=1e-12)
    np.testing.assert_allclose(y_read, y, rtol=1e-12)


def test_reproduce_prints_tables_and_writes_files(reproduce_data, tmp_path, monkeypatch, capsys):
    from skcath import protocol
    from skcath.protocol._report import TABLE_FILES

    path, X, y = reproduce_data
    monkeypatch.setattr(protocol, "FULL", _tiny_schedule("tiny-full"))
    import importlib.util

    figures = importlib.util.find_spec("matplotlib") is not None
    out = tmp_path / "results"
    argv = ["reproduce", "--data", str(path), "--out", str(out), "--n-jobs", "1", "--exclude-settings", "S00"]
    if not figures:
        argv.append("--no-figures")
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "Table I." in printed
    assert "schedule: tiny-full (2 setting folds per catheter, seeds [0])" in printed
    assert "not evaluated: ['S00']" in printed
    assert "Leave one catheter out" in printed

    files = {p.name for p in out.iterdir()}
    for key in ("table_1", "run_rmse", "run_rmse_by_seed", "paired", "loco", "cdf_at_5mm", "example"):
        assert TABLE_FILES[key] in files
    assert "timings.csv" in files
    if figures:
        assert {"rmse_boxes.png", "error_cdf.png", "new_catheter.png"} <= files
    assert re.search(rf"wrote {len(files)} files to ", printed)

    table_1 = pd.read_csv(out / TABLE_FILES["table_1"], index_col=0)
    assert list(table_1.index) == ["PCC", "PDL", "PDL+GRU"]
    assert list(table_1.columns) == ["C1", "C2", "pooled"]
    assert np.isfinite(table_1.to_numpy()).all()
    # the backbones learn nothing: their rows are the mean per-run RMSE of each
    # backbone calibrated on every run's own sweep, computed here from the data
    # (the file holds 4 decimals)
    from skcath.backbones import PCCBackbone, PDLBackbone
    from skcath.metrics import per_run_rmse

    tested = (X["setting"].astype(str) != "S00").to_numpy()
    Xt, yt = X[tested], y[tested]
    catheter_of = Xt.groupby("run", observed=True)["catheter"].first().astype(str)
    for name, Backbone in (("PCC", PCCBackbone), ("PDL", PDLBackbone)):
        runs = per_run_rmse(yt, Backbone().fit(Xt).predict(Xt), Xt)
        runs.index = runs.index.astype(str)
        by_catheter = runs.groupby(catheter_of.reindex(runs.index).to_numpy()).mean()
        assert table_1.loc[name, ["C1", "C2"]].to_numpy() == pytest.approx(
            by_catheter[["C1", "C2"]].to_numpy(), rel=0, abs=5e-5
        )
        assert table_1.loc[name, "pooled"] == pytest.approx(runs.mean(), rel=0, abs=5e-5)
    # the learned method, even this tiny, is far from a constant: the mean tip of
    # each catheter's motion rows (measured: 7.2 mm against 20.1 mm, pooled)
    motion = (Xt["phase"] == "motion").to_numpy()
    mean_tip = pd.DataFrame(yt[motion]).groupby(Xt.loc[motion, "catheter"].astype(str).to_numpy()).mean()
    constant = per_run_rmse(yt, mean_tip.loc[Xt["catheter"].astype(str)].to_numpy(), Xt).mean()
    assert table_1.loc["PDL+GRU", "pooled"] < 0.5 * constant
    run_rmse = pd.read_csv(out / TABLE_FILES["run_rmse"])
    expected_runs = set(X.loc[X["setting"].astype(str) != "S00", "run"].astype(str))
    assert set(run_rmse["run"]) == expected_runs
    assert set(run_rmse["method"]) == {"PCC", "PDL", "PDL+GRU", "PDL+GRU (LOCO)"}
    timings = pd.read_csv(out / "timings.csv")
    # one pretrained model per catheter, one fine-tuned model per fold
    assert sorted(timings["stage"]) == ["fine-tune"] * 4 + ["pretrain"] * 2


def test_reproduce_seeds_and_schedule_choice(reproduce_data, protocol_spy, tmp_path):
    from skcath import protocol

    path, X, y = reproduce_data
    base = ["reproduce", "--data", str(path), "--out", str(tmp_path), "--no-figures"]

    with pytest.raises(_Stop):
        main(base)
    call = protocol_spy[-1]
    assert call["schedule"] is protocol.FULL
    assert tuple(call["exclude_settings"]) == ()  # nothing excluded by default with --data
    assert call["n_jobs"] == -1
    assert len(call["X"]) == len(X)
    np.testing.assert_allclose(call["y"], y, rtol=1e-12)

    with pytest.raises(_Stop):
        main([*base, "--seeds", "3", "4", "3", "--n-jobs", "2", "--exclude-settings", "S00", "S01"])
    call = protocol_spy[-1]
    assert call["schedule"].seeds == (3, 4)
    assert call["schedule"].name == protocol.FULL.name
    assert call["schedule"].pretrain_params == protocol.FULL.pretrain_params
    assert call["n_jobs"] == 2
    assert list(call["exclude_settings"]) == ["S00", "S01"]

    with pytest.raises(_Stop):
        main([*base, "--quick"])
    assert protocol_spy[-1]["schedule"] is protocol.QUICK

    with pytest.raises(_Stop):
        main([*base, "--quick", "--seeds", "5"])
    schedule = protocol_spy[-1]["schedule"]
    assert schedule.seeds == (5,)
    assert (schedule.name, schedule.n_setting_folds) == (protocol.QUICK.name, protocol.QUICK.n_setting_folds)

    with pytest.raises(_Stop):
        main([*base, "--variants", "PDL+GRU", "PDL+MLP", "PDL+GRU"])
    schedule = protocol_spy[-1]["schedule"]
    assert schedule.variants == ("PDL+GRU", "PDL+MLP")
    assert schedule.finetune_params == protocol.FULL.finetune_params
    assert "frame" not in schedule.model_params  # the learners' own default

    with pytest.raises(_Stop):
        main([*base, "--quick", "--frame", "base"])
    schedule = protocol_spy[-1]["schedule"]
    assert schedule.model_params == {**protocol.QUICK.model_params, "frame": "base"}
    assert "frame" not in protocol.QUICK.model_params  # the shared schedule is not modified


def test_reproduce_builtin_benchmark_excludes_the_straight_setting(
    reproduce_data, protocol_spy, tmp_path, monkeypatch
):
    from skcath import datasets

    _, X, y = reproduce_data
    requested = {}

    def fake_benchmark(**kwargs):
        requested.update(kwargs)
        return Bunch(X=X, y=y)

    monkeypatch.setattr(datasets, "make_benchmark", fake_benchmark)
    with pytest.raises(_Stop):
        main(["reproduce", "--out", str(tmp_path), "--no-figures", "--mechanism", "bouc_wen"])
    assert tuple(protocol_spy[-1]["exclude_settings"]) == ("S00",)
    assert requested["mechanism"] == "bouc_wen"


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--n-jobs", "0"], "argument --n-jobs"),
        (["--n-jobs", "two"], "argument --n-jobs"),
        (["--seeds", "-1"], "argument --seeds: expected a non-negative"),
        (["--data", "does-not-exist.csv"], "argument --data"),
        (["--variants", "PDL+LSTM"], "argument --variants: unknown"),
        (["--variants", "PDL+MLP"], "argument --variants: 'PDL+GRU' is required"),
        (["--frame", "tip"], "argument --frame: invalid choice"),
    ],
)
def test_reproduce_bad_arguments_exit_2(extra, message, reproduce_data, tmp_path, monkeypatch, capsys):
    path, _, _ = reproduce_data
    monkeypatch.chdir(tmp_path)
    argv = ["reproduce", "--data", str(path), "--out", str(tmp_path / "out"), "--no-figures", *extra]
    with pytest.raises(SystemExit) as excinfo:
        main(argv)
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "error:" in err and message in err
    assert not (tmp_path / "out").exists()


def test_reproduce_single_catheter_is_a_usage_error(reproduce_data, tmp_path, capsys):
    _, X, y = reproduce_data
    one = (X["catheter"].astype(str) == "C1").to_numpy()
    frame = X[one].copy()
    for k, axis in enumerate("xyz"):
        frame[f"p_{axis}"] = y[one, k]
    path = tmp_path / "one.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(SystemExit) as excinfo:
        main(["reproduce", "--data", str(path), "--out", str(tmp_path / "out"), "--no-figures"])
    assert excinfo.value.code == 2
    assert "catheter" in capsys.readouterr().err


def _options(command):
    """The optional arguments of a sub-command, by option string."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return {action.option_strings[0]: action for action in sub._actions if action.option_strings}


@pytest.mark.parametrize(
    "option",
    ["--data", "--exclude-settings", "--mechanism", "--data-home", "--out", "--no-figures",
     "--n-jobs", "--seeds"],
)
def test_shared_arguments_are_the_same_in_every_command(option):
    repro, budget = _options("reproduce"), _options("calibration-budget")
    fields = ("dest", "default", "type", "nargs", "choices", "help", "metavar")
    assert [getattr(repro[option], f) for f in fields] == [getattr(budget[option], f) for f in fields]
    if option in ("--mechanism", "--data-home"):
        benchmark = _options("benchmark")[option]
        assert [getattr(benchmark, f) for f in fields] == [getattr(repro[option], f) for f in fields]


def test_variants_choices_come_from_the_registry():
    from skcath.protocol import VARIANTS

    text = _options("reproduce")["--variants"].help
    assert all(repr(name) in text for name in VARIANTS)
