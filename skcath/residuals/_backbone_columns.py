"""The backbone's nominal tip among the columns of recordings, as the residual learners read it."""

from __future__ import annotations

import numpy as np
import pandas as pd

from .. import _format as fmt
from ..backbones import BACKBONE_COLUMNS

__all__ = ["check_backbone_columns", "nominal_tip"]


def check_backbone_columns(X: pd.DataFrame, owner: str) -> None:
    """Raise a clear error unless ``X`` carries finite backbone columns ``b_x, b_y, b_z``."""
    missing = [c for c in BACKBONE_COLUMNS if c not in X.columns]
    if missing:
        raise ValueError(
            f"{owner} needs the backbone's nominal tip position in the columns "
            f"{list(BACKBONE_COLUMNS)}, but X has no column {missing}. Put a backbone "
            f"before it: Pipeline([('backbone', PDLBackbone()), ('residual', {owner}())])."
        )
    for c in BACKBONE_COLUMNS:
        values = pd.to_numeric(X[c], errors="coerce").to_numpy(dtype=np.float64)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"Column {c!r} must hold finite nominal tip positions (mm); row {i} "
                f"(run {X[fmt.RUN].iloc[i]!r}) holds {X[c].iloc[i]!r}."
            )


def nominal_tip(X: pd.DataFrame) -> np.ndarray:
    """The backbone columns ``b_x, b_y, b_z`` of ``X`` as an (n_samples, 3) float array (mm)."""
    return np.column_stack(
        [pd.to_numeric(X[c]).to_numpy(dtype=np.float64) for c in BACKBONE_COLUMNS]
    )
