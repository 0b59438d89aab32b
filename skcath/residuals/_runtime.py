"""Where and how the residual networks compute: torch threads and seeds, devices, the validation split."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import torch

__all__ = ["available_devices", "check_device"]


@contextmanager
def _torch_runtime(n_threads, seed):
    """Torch intra-op threads and a private, seeded random stream for one call."""
    previous = torch.get_num_threads()
    if n_threads is not None:
        torch.set_num_threads(int(n_threads))
    try:
        if seed is None:
            yield
        else:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(int(seed))
                yield
    finally:
        torch.set_num_threads(previous)


def available_devices():
    """The torch devices this machine can compute on: ``"cpu"``, then each GPU."""
    devices = ["cpu"]
    if torch.cuda.is_available():
        devices += [f"cuda:{k}" for k in range(torch.cuda.device_count())]
    if torch.backends.mps.is_available():
        devices.append("mps")
    return devices


def check_device(device, owner):
    """Raise a clear error unless torch can compute on ``device`` (a learner's parameter).

    Checked before any work, so that a missing GPU is reported before the
    data are prepared rather than by torch's own error at the first tensor.
    ``None`` (skorch: leave the network where it is) is accepted.
    """
    if device is None:
        return
    try:
        where = torch.device(device)
        if where.type != "cpu":
            torch.empty(0, device=where)
    except Exception as exc:  # torch raises RuntimeError, AssertionError, NotImplementedError
        raise ValueError(
            f"{owner} has device={device!r}, but torch cannot compute there on this "
            f"machine; the devices available are {available_devices()}. Pass "
            "device='cpu', or install a torch build for the GPU (docs/install.rst)."
        ) from exc


def _silent(*args, **kwargs):
    """Sink of the early-stopping message when ``verbose=0``."""


class _SettingHoldout:
    """Validation split that holds out whole shaft settings (all their repeats).

    Called by the net with the window dataset; ``X["group"]`` holds the code of
    the (catheter, setting) pair of every window.
    """

    def __init__(self, fraction, seed):
        self.fraction = fraction
        self.seed = seed

    def __call__(self, dataset, y=None, **kwargs):
        group = np.asarray(dataset.X["group"])
        unique = np.unique(group)
        if unique.size < 2:
            raise ValueError(
                "validation_fraction needs at least two shaft settings in the training "
                f"data to hold one out, got {unique.size}."
            )
        n_valid = min(max(1, round(self.fraction * unique.size)), unique.size - 1)
        rng = np.random.default_rng(self.seed)
        held = rng.choice(unique, size=n_valid, replace=False)
        is_valid = np.isin(group, held)
        train = torch.utils.data.Subset(dataset, np.flatnonzero(~is_valid).tolist())
        valid = torch.utils.data.Subset(dataset, np.flatnonzero(is_valid).tolist())
        return train, valid


def _not_prepared(learner, data):
    """Message for data given to the network that were not prepared from recordings."""
    name = type(learner).__name__
    return (
        f"{name} takes recordings in the long format (a DataFrame) in fit, predict and "
        f"predict_residual only; the network's methods (forward, forward_iter, infer) take "
        f"the input those prepare from recordings, not {type(data).__name__}. Use "
        f"{name}.predict for tip positions (mm) or predict_residual for the residual (mm)."
    )
