"""Cross-validation splitters for the evaluation protocol.

Hold out a shaft setting within its catheter (:class:`LeaveOneSettingOut`,
:class:`SettingGroupKFold`) or a whole catheter (:class:`LeaveOneCatheterOut`).
The splitters read the ``catheter`` and ``setting`` columns of the recordings
and are passed as ``cv=`` to scikit-learn's model-selection tools; see
``docs/evaluation.rst``.
"""

from ._split import LeaveOneCatheterOut, LeaveOneSettingOut, SettingGroupKFold, exclusion_set

__all__ = ["LeaveOneCatheterOut", "LeaveOneSettingOut", "SettingGroupKFold", "exclusion_set"]
