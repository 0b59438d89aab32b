"""Warnings and errors of skcath.

A leaf module: it imports nothing from the package, so that every other module
can import it.
"""

__all__ = [
    "FileSuffixWarning",
    "GroupsNotUsedWarning",
    "IncompatibleVersionError",
    "InconsistentVersionWarning",
    "MotorLimitWarning",
    "PickledFileError",
    "PipelineChangedWarning",
    "SampleRateWarning",
    "TruncatedFileWarning",
]


class InconsistentVersionWarning(UserWarning):
    """An estimator is unpickled under another skcath version than it was pickled with.

    Warned by :func:`skcath.persist.load` when the saved file's version differs
    from the running one, and by the skcath estimators themselves when they are
    unpickled directly (``pickle.load``, ``joblib.load``).

    Parameters
    ----------
    estimator_name : str
        Class name of the unpickled estimator.
    original_version : str
        skcath version that pickled it.
    current_version : str
        skcath version that unpickles it.
    """

    def __init__(self, *, estimator_name, original_version, current_version):
        self.estimator_name = estimator_name
        self.original_version = original_version
        self.current_version = current_version

    def __str__(self):
        return (
            f"{self.estimator_name} was pickled with skcath {self.original_version} and is "
            f"unpickled with skcath {self.current_version}; its predictions may differ or it may "
            "fail. Refit it with the running version, or install skcath "
            f"{self.original_version} to use it."
        )


class IncompatibleVersionError(ValueError):
    """A saved estimator was written by an incompatible skcath version.

    Raised by :func:`skcath.persist.load` before anything is unpickled; pass
    ``allow_version_mismatch=True`` to load the file anyway. See
    :func:`skcath.persist.is_compatible_version` for the rule.
    """


class PickledFileError(ValueError):
    """A file holds a pickle, which :func:`skcath.persist.load` does not unpickle by default.

    Unpickling runs any code the file contains. Raised before anything is
    unpickled; pass ``allow_pickle=True`` to load a file you trust, and save
    it again in the pickle-free default format.
    """


class TruncatedFileWarning(UserWarning):
    """A CSV file looks cut short; its last line was dropped.

    Warned by the readers of :mod:`skcath.io` when the last line of a CSV
    file does not end with a line break, or holds fewer fields than the
    header and the line before it: what a recording interrupted while the
    file was written leaves behind. The values of such a line cannot be
    trusted (a number may be cut short), so the line is not read. The
    message names the file and shows the line.
    """


class FileSuffixWarning(UserWarning):
    """A file written by :func:`skcath.persist.save` is not named ``*.skcath``.

    The file is a zip archive that only :func:`skcath.persist.load` reads: a
    suffix such as ``.joblib``, ``.pkl`` or ``.skops`` invites
    ``joblib.load``, ``pickle.load`` or ``skops.io.load``, which cannot open
    it. The file is written all the same.
    """


class GroupsNotUsedWarning(UserWarning):
    """``groups`` was given to a splitter of :mod:`skcath.model_selection`.

    Warned by ``split`` and ``get_n_splits`` of
    :class:`~skcath.model_selection.LeaveOneSettingOut`,
    :class:`~skcath.model_selection.SettingGroupKFold` and
    :class:`~skcath.model_selection.LeaveOneCatheterOut`: they group the rows
    by the ``catheter`` and ``setting`` columns of ``X`` and do not use
    ``groups``. Leave ``groups`` out, or use a scikit-learn group splitter
    (``GroupKFold``, ``LeaveOneGroupOut``) to fold by other groups.
    """


class PipelineChangedWarning(UserWarning):
    """The pipeline of a started :class:`~skcath.online.OnlineEstimator` has changed.

    :meth:`~skcath.online.OnlineEstimator.start` takes what the step needs
    from the fitted pipeline (the backbone's calibration on the sweep, the
    sweep context, the residual network's weights) and keeps it: refitting
    the pipeline in place, or setting its parameters, afterwards does not
    change the started estimator, which goes on stepping the pipeline as it
    was. Warned by :meth:`~skcath.online.OnlineEstimator.reset` and when a
    started estimator is unpickled, if the pipeline it holds differs from the
    one at ``start``. Call ``start(sweep)`` again to step the pipeline as it
    is.
    """


class SampleRateWarning(UserWarning):
    """A parameter that counts samples meets another rate than it was chosen at.

    Warned by :meth:`skcath.online.ShaftChangeDetector.start` when the sweep's
    times are at another rate than its ``rate_hz``, and when its per-sample
    CUSUM ``threshold`` or ``drift`` keeps its default (chosen at 10 Hz) at a
    rate more than 10 % from 10 Hz. The residual learners give their time
    scales in seconds and need no such warning.
    """


class MotorLimitWarning(UserWarning):
    """A motor command beyond the motors' range was clipped to it.

    Warned by :meth:`skcath.datasets.SimulatedCatheter.step` at the first
    command of a run that leaves ``[-motor_limit_deg, motor_limit_deg]``; the
    rig counts the clipped commands in ``n_clipped_``.
    """
