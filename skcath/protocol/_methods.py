"""The methods of the evaluation protocol, each described once.

A method is a geometric backbone alone (PCC, PDL) or a residual learner on
the PDL backbone (PDL+GRU, its torque/context ablations, PDL+MLP), trained
within the catheter or, for the catheter-held-out (LOCO) method, on the
other catheters only. :data:`METHODS` holds one :class:`Method` per name:
how it is built, how it is trained, its colour in the figures and its
*roles*, the tables and figures it appears in with its position there.
Every other part of the protocol (schedule, training, tables, report,
figures, calibration budget, command line) reads its names from here.

Roles
-----
``main``
    Table I, the box plots, error CDF and binned-error figures: the two
    backbones and the proposed method.
``torque_context``
    Table II, the torque x context ablation of the GRU residual.
``residual_learners``
    The MLP against the GRU residual (table and figure).
``loco``
    The catheter-held-out table: PDL, the proposed method trained within the
    catheter, and trained on the other catheters only.
``new_catheter``
    The figure of the proposed method within the catheter and held out.
``conditioning``
    The figure of the GRU residual with and without its torque and context
    inputs.
``example``
    The method of the motion example, the first one that was run.
``budget``
    The methods scored at every calibration budget.
``adaptation``
    The sweep-adaptation table: the backbone and the proposed method
    without and with the hysteresis of each run identified on its own
    tracked sweep, within the catheter and with the catheter held out.

Sweep adaptation
----------------
A method with ``adapt=True`` uses the backbone with
``hysteresis="play"``: each run's motor angles pass through a play whose
half-width is identified on the run's own tracked sweep
(:func:`skcath.backbones.identify_play_width`), and its residual learner is
trained and evaluated on that backbone's nominal tip. The paper's methods
keep ``adapt=False``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from sklearn.utils._param_validation import StrOptions, validate_params

from ..backbones import PCCBackbone, PDLBackbone
from ..residuals import GRUResidual, MLPResidual

__all__ = [
    "BACKBONES",
    "BACKBONE_METHODS",
    "COMPARISONS",
    "LEARNERS",
    "LOCO_METHOD",
    "LOCO_VARIANT",
    "MAIN_METHODS",
    "METHODS",
    "Method",
    "PROPOSED_METHOD",
    "ADAPTED_BACKBONE",
    "ADAPTED_METHOD",
    "LOCO_METHODS",
    "ROLES",
    "TORQUE_CONTEXT",
    "backbone_method",
    "VARIANTS",
    "comparison_label",
    "make_learner",
    "methods_with_role",
]

#: Backbone estimators by the name a :class:`Method` gives them.
BACKBONES = MappingProxyType({"pcc": PCCBackbone, "pdl": PDLBackbone})

#: Residual learners by the name a :class:`Method` gives them.
LEARNERS = MappingProxyType({"gru": GRUResidual, "mlp": MLPResidual})

#: Tables and figures that list methods (the roles of a :class:`Method`).
ROLES = (
    "main",
    "torque_context",
    "residual_learners",
    "loco",
    "new_catheter",
    "conditioning",
    "example",
    "budget",
    "adaptation",
)

#: Backbone parameters of the methods with ``adapt=True``.
ADAPTED_BACKBONE = MappingProxyType({"hysteresis": "play"})


@dataclass(frozen=True)
class Method:
    """One method of the protocol: how it is built, trained and reported.

    Parameters
    ----------
    name : str
        Label in every table, figure and result (e.g. ``"PDL+GRU"``).
    backbone : {"pcc", "pdl"}
        Geometric backbone (:data:`BACKBONES`); for a learned method, the
        backbone whose nominal tip the residual corrects.
    learner : {"gru", "mlp"} or None, default=None
        Residual learner (:data:`LEARNERS`); None for the backbone alone.
    use_torque : bool, default=True
        The learner reads the motor torques (its ``use_torque``).
    use_context : bool, default=True
        The learner reads the sweep context (its ``use_context``).
    loco : bool, default=False
        Trained on the other catheters only: the pretrained model of the
        learned method with the same learner and inputs, never fine-tuned.
    adapt : bool, default=False
        The backbone identifies each run's hysteresis on its own tracked
        sweep (:data:`ADAPTED_BACKBONE`); see *Sweep adaptation* above.
    colour : str, default="tab:gray"
        matplotlib colour of the method in every figure.
    roles : mapping of str to int
        Tables and figures (:data:`ROLES`) the method appears in, each with
        its position there (0 first).
    """

    name: str
    backbone: str
    learner: str | None = None
    use_torque: bool = True
    use_context: bool = True
    loco: bool = False
    adapt: bool = False
    colour: str = "tab:gray"
    roles: Mapping[str, int] = field(default_factory=dict)

    @property
    def is_variant(self):
        """True for a learned method trained within the catheter (a key of :data:`VARIANTS`)."""
        return self.learner is not None and not self.loco

    @property
    def backbone_params(self):
        """Parameters of the method's backbone estimator (:data:`ADAPTED_BACKBONE` or none)."""
        return dict(ADAPTED_BACKBONE) if self.adapt else {}


def _registry(*methods):
    """The methods by name, after checking that their names, keys and roles are consistent."""
    by_name = {}
    for method in methods:
        if method.name in by_name:
            raise ValueError(f"method {method.name!r} is described twice.")
        if method.backbone not in BACKBONES or method.learner not in (None, *LEARNERS):
            raise ValueError(f"method {method.name!r} names an unknown backbone or learner.")
        if set(method.roles) - set(ROLES):
            raise ValueError(f"method {method.name!r} has roles outside {ROLES}.")
        by_name[method.name] = method
    return MappingProxyType(by_name)


#: Every method of the protocol, in the order of the results and the tables.
METHODS = _registry(
    Method("PCC", "pcc", colour="tab:blue", roles={"main": 0, "budget": 0}),
    Method(
        "PDL", "pdl", colour="tab:orange",
        roles={"main": 1, "loco": 0, "example": 1, "budget": 1, "adaptation": 0},
    ),
    Method("PDL+adapt", "pdl", adapt=True, colour="tab:cyan", roles={"adaptation": 1}),
    Method(
        "PDL+GRU", "pdl", "gru", colour="tab:green",
        roles={"main": 2, "torque_context": 3, "residual_learners": 1, "loco": 1,
               "new_catheter": 0, "conditioning": 0, "example": 0, "budget": 2,
               "adaptation": 2},
    ),
    Method("PDL+GRU+adapt", "pdl", "gru", adapt=True, colour="darkgreen", roles={"adaptation": 3}),
    Method("PDL+MLP", "pdl", "mlp", colour="tab:red", roles={"residual_learners": 0}),
    Method(
        "PDL+GRU (no torque)", "pdl", "gru", use_torque=False, colour="tab:purple",
        roles={"torque_context": 2, "conditioning": 1},
    ),
    Method(
        "PDL+GRU (no context)", "pdl", "gru", use_context=False, colour="tab:brown",
        roles={"torque_context": 1, "conditioning": 2},
    ),
    Method(
        "PDL+GRU (no torque, no context)", "pdl", "gru", use_torque=False, use_context=False,
        colour="tab:pink", roles={"torque_context": 0, "conditioning": 3},
    ),
    Method(
        "PDL+GRU (LOCO)", "pdl", "gru", loco=True, colour="tab:olive",
        roles={"loco": 2, "new_catheter": 1, "adaptation": 4},
    ),
    Method(
        "PDL+GRU+adapt (LOCO)", "pdl", "gru", loco=True, adapt=True, colour="olive",
        roles={"adaptation": 5},
    ),
)


@validate_params({"role": [StrOptions(set(ROLES))]}, prefer_skip_nested_validation=True)
def methods_with_role(role):
    """Names of the methods of a table or figure, in their order there.

    Parameters
    ----------
    role : str
        One of :data:`ROLES`.

    Returns
    -------
    names : tuple of str
    """
    members = [method for method in METHODS.values() if role in method.roles]
    return tuple(method.name for method in sorted(members, key=lambda m: m.roles[role]))


#: Learned methods trained within the catheter: name -> (learner, use_torque, use_context).
#: ``PDL+GRU`` is the proposed estimator; the others are the paper's ablations.
VARIANTS = MappingProxyType({
    name: (method.learner, method.use_torque, method.use_context)
    for name, method in METHODS.items() if method.is_variant
})

#: The backbones alone, in the order of the results.
BACKBONE_METHODS = tuple(name for name, method in METHODS.items() if method.learner is None)

#: Methods of Table I and of the distribution figures.
MAIN_METHODS = methods_with_role("main")

#: The proposed method: the learned method of Table I.
(PROPOSED_METHOD,) = (name for name in MAIN_METHODS if METHODS[name].learner is not None)


def _loco_variant(method):
    """The variant whose pretrained models the LOCO ``method`` reports (same learner and inputs)."""
    fields = ("backbone", "adapt", "learner", "use_torque", "use_context")
    sources = [
        name for name, other in METHODS.items()
        if other.is_variant and all(getattr(other, f) == getattr(method, f) for f in fields)
    ]
    if len(sources) != 1:
        raise ValueError(f"the LOCO method {method.name!r} must match one variant; got {sources}.")
    return sources[0]


#: The catheter-held-out methods: name -> the variant whose pretrained models they report.
LOCO_METHODS = MappingProxyType({
    name: _loco_variant(method) for name, method in METHODS.items() if method.loco
})

#: The paper's catheter-held-out method: the pretrained models of :data:`LOCO_VARIANT`.
(LOCO_METHOD,) = (name for name in LOCO_METHODS if not METHODS[name].adapt)

#: The learned method whose pretrained models are reported as :data:`LOCO_METHOD`.
LOCO_VARIANT = LOCO_METHODS[LOCO_METHOD]


@validate_params({"method": [StrOptions(set(METHODS))]}, prefer_skip_nested_validation=True)
def backbone_method(method):
    """The backbone-only method whose nominal tip ``method`` uses (itself for a backbone).

    Parameters
    ----------
    method : str
        A name of :data:`METHODS`.

    Returns
    -------
    name : str
        The backbone method with the same backbone and ``adapt``.
    """
    spec = METHODS[method]
    (name,) = (
        name for name, other in METHODS.items()
        if other.learner is None and (other.backbone, other.adapt) == (spec.backbone, spec.adapt)
    )
    return name


def _yes_no(flag):
    return "Yes" if flag else "No"


def _adapted(name, adapt=True):
    """The method that is ``name`` with (or, ``adapt=False``, without) sweep adaptation, or None."""
    spec = METHODS[name]
    fields = ("backbone", "learner", "use_torque", "use_context", "loco")
    matches = [
        other_name for other_name, other in METHODS.items()
        if other.adapt == adapt and all(getattr(other, f) == getattr(spec, f) for f in fields)
    ]
    return matches[0] if matches else None


#: The proposed method with sweep adaptation (None if the registry has none).
ADAPTED_METHOD = _adapted(PROPOSED_METHOD)


#: Table II: (torque, context) -> method.
TORQUE_CONTEXT = MappingProxyType({
    (_yes_no(METHODS[name].use_torque), _yes_no(METHODS[name].use_context)): name
    for name in methods_with_role("torque_context")
})


def comparison_label(baseline, candidate):
    """Label of the paired comparison of two methods, ``"baseline -> candidate"``."""
    return f"{baseline} -> {candidate}"


def _comparisons():
    """Paired comparisons of the protocol, in the order of the paired table.

    Every other method of Table I and of the residual learners against the
    proposed method; each input of the torque x context grid added, with and
    without the other input; the catheter held out against the setting held
    out.
    """
    baselines = dict.fromkeys([*MAIN_METHODS, *methods_with_role("residual_learners")])
    pairs = {
        comparison_label(base, PROPOSED_METHOD): (base, PROPOSED_METHOD)
        for base in baselines if base != PROPOSED_METHOD
    }
    grid = {(METHODS[n].use_torque, METHODS[n].use_context): n for n in TORQUE_CONTEXT.values()}
    for other in (True, False):
        pairs[f"torque ({'with' if other else 'without'} context)"] = (grid[False, other], grid[True, other])
    for other in (True, False):
        pairs[f"context ({'with' if other else 'without'} torque)"] = (grid[other, False], grid[other, True])
    pairs["catheter held out -> setting held out"] = (LOCO_METHOD, LOCO_VARIANT)
    adapted = {name: spec for name, spec in METHODS.items() if spec.adapt and spec.learner}
    for name, spec in adapted.items():
        plain = LOCO_METHOD if spec.loco else PROPOSED_METHOD
        scope = "catheter held out" if spec.loco else "setting held out"
        pairs[f"sweep adaptation ({scope})"] = (plain, name)
    return MappingProxyType(pairs)


#: Paired comparisons: label -> (baseline, candidate); the reduction is baseline - candidate.
COMPARISONS = _comparisons()


@validate_params(
    {"method": [StrOptions({name for name, m in METHODS.items() if m.learner is not None})]},
    prefer_skip_nested_validation=False,
)
def make_learner(method, **params):
    """A fresh, unfitted residual learner of a learned method.

    Parameters
    ----------
    method : str
        Name of a learned method of :data:`METHODS` (e.g. ``"PDL+GRU"``).
    **params
        Further parameters of the learner (``random_state``, ``max_epochs``,
        ``module__hidden_size``, ...). The method fixes ``use_torque`` and
        ``use_context``.

    Returns
    -------
    learner : GRUResidual or MLPResidual
        The method's learner with its inputs and ``params``.

    Raises
    ------
    ValueError
        If ``method`` is not a learned method, or ``params`` sets an input
        the method fixes.
    """
    spec = METHODS[method]
    inputs = {"use_torque": spec.use_torque, "use_context": spec.use_context}
    fixed = sorted(set(inputs) & set(params))
    if fixed:
        raise ValueError(
            f"the method {method!r} sets {fixed} itself; choose the method with the inputs "
            f"wanted among {list(VARIANTS)} instead."
        )
    return LEARNERS[spec.learner](**inputs, **params)
