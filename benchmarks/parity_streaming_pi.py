"""Parity of the streaming and exported step with ``predict`` for backbones with ``hysteresis="pi"``.

Data: the simulated instrument of one, two or three motors
(``make_benchmark(n_motors=..., n_catheters=1, n_runs=1, random_state=0)``,
cached in the skcath data folder). The backbone (``hysteresis="pi"``) and a
small residual (one epoch, hidden size 8) are fitted on the run of setting
S02 (its first 200 motion rows); the run of setting S05 (its sweep and its
first ``--motion`` motion rows) is then predicted with ``predict`` and
stepped sample by sample by ``OnlineEstimator`` (float64) on both engines,
with the samples' times ``t`` and without, and by its exported whole step
(ONNX, run by onnxruntime on one thread, fed ``dt``). The table gives the
largest difference (mm) over the motion samples: the step against the
float64 ``predict`` (``module_.double()``), the ONNX graph against the
float32 ``predict`` (as fitted), the size of the ONNX file (bytes) and the
identified PI (weights, dead band, creep gain). A second table gives the
size of the ONNX file of the PDL backbone with ``hysteresis=None``,
``"play"`` and ``"pi"``, alone and with the GRU (the same fits).

Usage (from the repository root)::

    .venv/bin/python benchmarks/parity_streaming_pi.py
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
from sklearn.pipeline import Pipeline

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _helpers import instrument, pi_pipelines, tiny_residual  # noqa: E402

from skcath.backbones import PDLBackbone  # noqa: E402
from skcath.online import OnlineEstimator, export  # noqa: E402
from skcath.residuals import GRUResidual, NoResidual  # noqa: E402

CASES = [("pdl", "gru", 2), ("pdl", "none", 2), ("pcc", "mlp", 2), ("polynomial", "none", 1),
         ("polynomial", "gru", 3)]


def _onnx(est, folder, samples, dt):
    import onnxruntime as ort

    path = export(est, Path(folder) / "step.onnx")
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    state = np.zeros((1, session.get_inputs()[1].shape[1]))
    reset, tips = np.array([True]), []
    for sample, step in zip(samples, dt):
        tip, state, _ = session.run(None, {"sample": sample[None], "state": state,
                                           "reset": reset, "dt": np.array([step])})
        reset = np.array([False])
        tips.append(tip[0])
    return np.array(tips), os.path.getsize(path)


def _case(backbone_name, kind, n_motors, n_motion, folder):
    pipe, pipe64, run, motion = pi_pipelines(backbone_name, kind, n_motors, n_motion)
    pred32, pred64 = pipe.predict(run)[motion], pipe64.predict(run)[motion]
    row = [f"{backbone_name}, {kind}, {n_motors} motor(s)"]
    for engine in ("numba", "numpy"):
        est = OnlineEstimator(pipe64, engine=engine).start(run[~motion])
        samples = run.loc[motion, list(est.channels_)].to_numpy()
        times = run.loc[motion, "t"].to_numpy()
        plain = np.array([est.step(*s) for s in samples])
        est.reset()
        timed = np.array([est.step(*s, t=t) for s, t in zip(samples, times)])
        row.append(max(np.abs(plain - pred64).max(), np.abs(timed - pred64).max()))
    dt = np.diff(times, prepend=run.loc[~motion, "t"].iloc[-1])
    tips, size = _onnx(est, folder, samples, dt)
    model = est.hysteresis_
    row += [np.abs(tips - pred32).max(), size,
            " ".join(f"{w:.2f}" for w in model.weights), model.dead_band, model.creep_gain]
    return row


def _sizes(folder):
    """ONNX bytes of the PDL step (alone, with the GRU) by hysteresis."""
    train, y = instrument(2, ["S02"], 200)
    run, _ = instrument(2, ["S05"], 10)
    sweep = run[(run["phase"] == "sweep").to_numpy()]
    rows = []
    for hysteresis in (None, "play", "pi"):
        backbone = PDLBackbone(hysteresis=hysteresis).fit(train, y)
        sizes = []
        for residual in (NoResidual(), tiny_residual(GRUResidual, max_epochs=1)):
            pipe = Pipeline([("backbone", backbone),
                             ("residual", residual.fit(backbone.transform(train), y))])
            est = OnlineEstimator(pipe, engine="numpy").start(sweep)
            sizes.append(os.path.getsize(export(est, Path(folder) / "size.onnx")))
        rows.append((hysteresis, *sizes))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--motion", type=int, default=120, help="motion rows of the test run")
    args = parser.parse_args(argv)
    print("| case | numba vs predict float64 (mm) | numpy vs predict float64 (mm) | "
          "ONNX vs predict float32 (mm) | ONNX bytes | PI weights | dead band (deg) | "
          "creep gain |")
    print("|---|---:|---:|---:|---:|---|---:|---:|")
    with tempfile.TemporaryDirectory() as folder, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for case in CASES:
            r = _case(*case, args.motion, folder)
            print(f"| {r[0]} | {r[1]:.1e} | {r[2]:.1e} | {r[3]:.1e} | {r[4]:,} | {r[5]} | "
                  f"{r[6]:.2f} | {r[7]:.3f} |", flush=True)
        print("\n| PDL, hysteresis | ONNX bytes, backbone only | ONNX bytes, with the GRU |")
        print("|---|---:|---:|")
        for hysteresis, alone, gru in _sizes(folder):
            print(f"| {hysteresis} | {alone:,} | {gru:,} |")


if __name__ == "__main__":
    main()
