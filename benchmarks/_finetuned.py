"""Within-catheter predictions of the benchmarks: pretrained models fine-tuned on every setting-held-out fold."""

import numpy as np

from skcath.protocol import finetune_models


def within_predictions(X, y, folds, schedule, pretrained, variant, n_jobs):
    """Fine-tune ``variant``'s pretrained models on each fold of ``folds.within``, as the protocol does.

    Returns the predictions (mm) in the rows of ``X``, each fold's test rows
    filled and NaN elsewhere, and the fine-tunings' timings.
    """
    out = finetune_models(X, y, folds.within, schedule, pretrained, variants=(variant,), n_jobs=n_jobs)
    pred = np.full((len(X), 3), np.nan)
    for (_, _, number), values in out.predictions.items():
        pred[folds.within[number].test] = values[0]
    return pred, out.timings
