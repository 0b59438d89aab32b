"""Cross-validation splitters for the evaluation protocol.

Hold out a shaft setting within its catheter (:class:`LeaveOneSettingOut`,
:class:`SettingGroupKFold`) or a whole catheter (:class:`LeaveOneCatheterOut`).
These splitters read the ``catheter`` and ``setting`` columns of the
recordings and are passed as ``cv=`` to scikit-learn's model-selection tools;
see ``docs/evaluation.rst``. Inside runs, :class:`BlockKFold` holds out
interleaved contiguous blocks of their motion rows.
"""

from ._blocks import BlockKFold
from ._split import LeaveOneCatheterOut, LeaveOneSettingOut, SettingGroupKFold, exclusion_set

__all__ = [
    "BlockKFold",
    "LeaveOneCatheterOut",
    "LeaveOneSettingOut",
    "SettingGroupKFold",
    "exclusion_set",
]
