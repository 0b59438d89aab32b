"""Training schedules of the evaluation protocol: which models, seeds and folds."""

from __future__ import annotations

from dataclasses import dataclass, field

from sklearn.utils._param_validation import StrOptions, validate_params

from ._methods import VARIANTS

__all__ = ["Schedule", "QUICK", "FULL", "get_schedule"]


@dataclass(frozen=True)
class Schedule:
    """How much training the protocol spends.

    Every learned method is trained in two stages, as in the paper: a model
    is pretrained once per held-out catheter on all the *other* catheters
    (that model is also the leave-one-catheter-out estimator), then, within
    the held-out catheter, fine-tuned from it on the settings of each fold's
    training set and evaluated on the fold's held-out settings. The test runs
    of a fold therefore never reach pretraining, fine-tuning or the
    normalisation statistics (which come from the pretraining data).

    Parameters
    ----------
    name : str
        Label printed with the results.
    seeds : tuple of int
        Seeds of the learned models; errors are averaged over them.
    n_setting_folds : int or None
        None holds out one setting at a time within each catheter
        (:class:`~skcath.model_selection.LeaveOneSettingOut`, the paper's
        protocol); an int splits each catheter's settings into that many
        groups (:class:`~skcath.model_selection.SettingGroupKFold`).
    variants : tuple of str
        Names of the learned methods to run (keys of ``VARIANTS``).
    model_params : dict
        Parameters shared by both stages (architecture, windows).
    pretrain_params : dict
        Parameters of the pretraining stage (epochs, learning rate).
    finetune_params : dict
        Parameters of the fine-tuning stage.
    adapt_pretrain_params : dict or None, default=None
        Pretraining of the sweep-adapted methods (``adapt=True``). None
        pretrains them from scratch with ``pretrain_params``, as every other
        method; a dict continues instead the pretrained model of the same
        method without adaptation (same seed, same training catheters) on
        the adapted backbone's nominal tip, with these parameters (the
        network, its normalisation statistics and ``model_params`` are kept).
    """

    name: str
    seeds: tuple = (0, 1, 2)
    n_setting_folds: int | None = None
    variants: tuple = tuple(VARIANTS)
    model_params: dict = field(default_factory=dict)
    pretrain_params: dict = field(default_factory=dict)
    finetune_params: dict = field(default_factory=dict)
    adapt_pretrain_params: dict | None = None


#: The paper's protocol: one setting held out at a time, three seeds, every
#: variant, the learners' default architecture. Long pretraining and a short
#: fine-tuning (30 and 2 epochs, fine-tuned in batches of 32 windows), chosen
#: on catheter C1 (pretrained on C2-C4). The sweep-adapted methods continue
#: the pretrained model of their method without adaptation for 5 epochs at
#: 3e-3 (chosen on C1) instead of a pretraining of their own.
FULL = Schedule(
    name="full",
    seeds=(0, 1, 2),
    n_setting_folds=None,
    pretrain_params={"max_epochs": 30, "lr": 1e-2},
    finetune_params={"max_epochs": 2, "lr": 3e-3, "batch_size": 32},
    adapt_pretrain_params={"max_epochs": 5, "lr": 3e-3},
)

#: A short version for a first look (about three minutes on two CPU cores):
#: one seed, four setting folds per catheter, smaller networks and fewer
#: epochs. Its numbers are higher than the full protocol's. Its adapted
#: methods are pretrained from scratch, as the others.
QUICK = Schedule(
    name="quick",
    seeds=(0,),
    n_setting_folds=4,
    model_params={"module__hidden_size": 64, "window_step_s": 20.0},
    pretrain_params={"max_epochs": 4, "lr": 1e-2},
    finetune_params={"max_epochs": 3, "lr": 3e-3},
)


#: The named schedules.
_NAMED = {"full": FULL, "quick": QUICK}

#: Constraint of a ``schedule`` parameter: a named schedule or a Schedule.
SCHEDULE_CONSTRAINT = [StrOptions(set(_NAMED)), Schedule]


@validate_params({"schedule": SCHEDULE_CONSTRAINT}, prefer_skip_nested_validation=True)
def get_schedule(schedule):
    """A :class:`Schedule` from its name or a Schedule, checked.

    Parameters
    ----------
    schedule : {"full", "quick"} or Schedule
        A named schedule (:data:`FULL`, :data:`QUICK`) or a schedule of one's
        own.

    Returns
    -------
    schedule : Schedule

    Raises
    ------
    ValueError
        If a Schedule names an unknown variant (:data:`VARIANTS`), no seed
        or a seed twice.
    """
    if not isinstance(schedule, Schedule):
        return _NAMED[schedule]
    unknown = sorted(set(schedule.variants) - set(VARIANTS))
    if unknown:
        raise ValueError(
            f"schedule.variants has unknown names {unknown}; expected names from {list(VARIANTS)}."
        )
    if not schedule.seeds:
        raise ValueError("schedule.seeds must name at least one seed.")
    if len(set(schedule.seeds)) != len(schedule.seeds):
        raise ValueError(f"schedule.seeds must not repeat a seed; got {schedule.seeds}.")
    return schedule
