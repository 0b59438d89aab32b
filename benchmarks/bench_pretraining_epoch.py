"""Seconds per pretraining epoch of PDL+GRU on this machine, and what the full protocol's pretraining costs.

The full protocol's wall time (``python -m skcath reproduce``) is almost all
training (``docs/studies/results.rst``, *Where the time goes*), and training time
follows the speed of the machine on the day. This script times the
protocol's pretraining of PDL+GRU for one held-out catheter (the full
network, one torch thread, learning rate :math:`10^{-2}`, on the default
benchmark's runs of the three other catheters) for 1 and for 3 epochs, and
prints the seconds per epoch (the difference over two epochs), the fixed
cost, and the time of one full-schedule pretraining (30 epochs) they give.
Run it next to a protocol's ``timings.csv`` to tell a slower machine from
slower code: two checkouts timed back to back on one machine compare the
code.

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_pretraining_epoch.py
"""

import argparse
import time

import numpy as np
import torch
from _machine import machine_lines

import skcath
from skcath.datasets import make_benchmark
from skcath.protocol import FULL, learner_input, make_learner


def _fit_seconds(X, y, epochs):
    """Wall time (s) of fitting PDL+GRU for ``epochs`` epochs with the full schedule's learning rate."""
    learner = make_learner("PDL+GRU", random_state=0, n_threads=1, max_epochs=epochs,
                           lr=FULL.pretrain_params["lr"], **FULL.model_params)
    start = time.perf_counter()
    learner.fit(X, y)
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--held-out", default="C1", help="catheter left out of the pretraining")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for line in machine_lines():
        print(line)
    print(f"skcath {skcath.__version__}")
    data = make_benchmark()
    train = (data.X["catheter"] != args.held_out).to_numpy()
    X, y = learner_input(data.X[train]), np.asarray(data.y)[train]
    one, three = _fit_seconds(X, y, 1), _fit_seconds(X, y, 3)
    epoch = (three - one) / 2.0
    fixed = one - epoch
    epochs = FULL.pretrain_params["max_epochs"]
    print(f"\nPDL+GRU pretraining on {X['run'].nunique()} runs ({len(X)} rows), one thread:")
    print("| epochs | wall time (s) |\n|---:|---:|")
    print(f"| 1 | {one:.1f} |\n| 3 | {three:.1f} |")
    print(f"\nper epoch {epoch:.1f} s, fixed {fixed:.1f} s; a full-schedule pretraining "
          f"({epochs} epochs) about {fixed + epochs * epoch:.0f} s")


if __name__ == "__main__":
    main()
