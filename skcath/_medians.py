"""Medians of values within groups (the runs of recordings), without a loop over the groups."""

from __future__ import annotations

import numpy as np

__all__ = ["group_medians"]


def group_medians(values: np.ndarray, codes: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of ``values`` within each group; NaN for a group without values.

    The values sorted by group and value (a sort by value, then a stable
    radix sort of the small integer codes), then the middle element(s) of
    every group's slice: no loop over the groups.
    """
    counts = np.bincount(codes, minlength=n_groups)
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    by_value = np.argsort(values)
    small = codes[by_value].astype(np.min_scalar_type(max(n_groups - 1, 0)), copy=False)
    ordered = values[by_value[np.argsort(small, kind="stable")]]
    medians = np.full(n_groups, np.nan)
    has = counts > 0
    low = starts[has] + (counts[has] - 1) // 2
    high = starts[has] + counts[has] // 2
    medians[has] = 0.5 * (ordered[low] + ordered[high])
    return medians
