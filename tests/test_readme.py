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


# The README's own-data example, run as a user runs it: simulated recordings
# written as CSV files in the user's naming (scalar-last quaternions, no phase
# or id columns) and a manifest, read back, cross-validated, streamed, exported,
# saved and loaded. Six shaft settings of one simulated catheter, one run each.
OWN_SETTINGS = ["S01", "S03", "S05", "S09", "S12", "S16"]
#: The user's column for each sensor column of the simulator.
OWN_SENSOR_COLUMNS = {
    f"{sensor}_{kind}{axis}": f"{sensor}_{axis}_mm" if kind == "p" else f"{sensor}_q{axis}"
    for sensor in ("tip", "base")
    for kind, axes in (("p", "xyz"), ("q", "xyzw"))
    for axis in axes
}


def _readme_manifest_header():
    """Column names of the manifest shown in the README (its ``text`` block)."""
    text = README.read_text(encoding="utf-8")
    blocks = re.findall(r"^```text\n(.*?)^```", text, flags=re.M | re.S)
    headers = [block.splitlines()[0] for block in blocks if block.startswith("path,")]
    assert len(headers) == 1, "README.md must show one manifest (a text block starting 'path,')"
    return headers[0].split(",")


@pytest.fixture(scope="module")
def own_recordings(tmp_path_factory):
    """Folder with ``recordings/`` as the README describes it, and the truth."""
    from skcath.datasets import make_benchmark

    data = make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path_factory.mktemp("data"))
    folder = tmp_path_factory.mktemp("own")
    (folder / "recordings").mkdir()
    header = _readme_manifest_header()
    rows, truth = [], []
    for info in data.runs[data.runs["setting"].isin(OWN_SETTINGS)].itertuples():
        rows_of_run = (data.X["run"] == info.run).to_numpy()
        X, sensors = data.X[rows_of_run], data.sensors[rows_of_run]
        own = pd.DataFrame(
            {
                "time_s": X["t"].to_numpy(),
                "motorA_deg": X["q1"].to_numpy(),
                "motorB_deg": X["q2"].to_numpy(),
                "torqueA_mNm": X["tau1"].to_numpy(),
                "torqueB_mNm": X["tau2"].to_numpy(),
                **{own: sensors[name].to_numpy() for name, own in OWN_SENSOR_COLUMNS.items()},
            }
        )
        name = f"A_{info.setting}_1.csv"
        own.to_csv(folder / "recordings" / name, index=False)
        ids = {"path": name, "catheter": "A", "setting": info.setting,
               "run": f"A-{info.setting}-1", "n_sweep": info.n_sweep}
        rows.append({column: ids[column] for column in header})
        truth.append((X["phase"].to_numpy(), data.y[rows_of_run]))
    pd.DataFrame(rows, columns=header).to_csv(folder / "recordings" / "manifest.csv", index=False)
    phase = np.concatenate([p for p, _ in truth])
    return folder, phase, np.concatenate([y for _, y in truth])


def _baseline_scores(estimator, X, y, cv):
    """Mean per-run RMSE (mm) of each fold of ``cv``."""
    from sklearn.model_selection import cross_validate

    from skcath.metrics import run_rmse_scorer

    return -cross_validate(estimator, X, y, cv=cv, scoring=run_rmse_scorer)["test_score"]


def test_readme_own_data_example(own_recordings, monkeypatch, capsys):
    """From CSV files to a loaded estimator streaming, with numbers a wrong model fails."""
    from sklearn.dummy import DummyRegressor
    from sklearn.pipeline import Pipeline

    from skcath import persist
    from skcath.backbones import PDLBackbone
    from skcath.online import OnlineEstimator, export

    folder, phase, truth = own_recordings
    monkeypatch.chdir(folder)
    namespace = {}
    exec(compile(_block_using("read_recordings"), "README.md", "exec"), namespace)
    X, y, cv = namespace["X"], namespace["y"], namespace["cv"]

    # Read as written: the sweep where the manifest puts it, and the tip in the
    # base frame from scalar-last quaternions (declared "wxyz", it is off by cm).
    assert X["run"].nunique() == len(OWN_SETTINGS)
    assert (X["phase"].astype(str).to_numpy() == phase).all()
    finite = np.isfinite(truth).all(axis=1)
    np.testing.assert_allclose(y[finite], truth[finite], rtol=0, atol=1e-9)

    # Accuracy with the settings held out. The backbone must halve the error of
    # the mean tip (measured: 7.0 mm against 18.0 mm), and the residual must
    # improve on the backbone by a margin (measured: 6.29 mm against 7.02 mm,
    # 0.73 mm better; the bound asks for 0.3 mm).
    gru = -namespace["scores"]["test_score"]
    assert len(gru) == cv.get_n_splits(X) == 3
    assert f"PDL+GRU: {gru.mean():.2f} mm" in capsys.readouterr().out
    pdl = _baseline_scores(Pipeline([("backbone", PDLBackbone())]), X, y, cv)
    constant = _baseline_scores(DummyRegressor(), X, y, cv)
    assert pdl.mean() <= 0.5 * constant.mean(), (pdl, constant)
    assert gru.mean() <= pdl.mean() - 0.3, (gru, pdl)

    # The stream is what predict gives for the same run (float64 step against
    # the float32 network of predict).
    original = namespace["est"].pipeline
    run, tips = namespace["run"], namespace["tips"]
    motion = (run["phase"] == "motion").to_numpy()
    assert tips.shape == (motion.sum(), 3)
    np.testing.assert_allclose(tips, original.predict(run)[motion], rtol=0, atol=1e-4)

    # The loaded pipeline streams bit for bit as the saved one, and its started
    # estimator exports the same whole-step graph.
    loaded = namespace["pipe"]
    assert loaded is not original
    again = OnlineEstimator(loaded).start(run[~motion])
    streamed = np.array([again.step(*s) for s in run.loc[motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()])
    np.testing.assert_array_equal(streamed, tips)
    assert isinstance(persist.load("pdl_gru.skcath")["residual"], type(original["residual"]))
    export(again, "loaded_step.onnx")
    assert (folder / "loaded_step.onnx").read_bytes() == (folder / "pdl_gru_step.onnx").read_bytes()
