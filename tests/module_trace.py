"""The modules of skcath a call crosses, recorded with ``sys.setprofile``.

Used by ``tests/test_start_path.py`` and ``benchmarks/trace_start_path.py``
(imported as ``from module_trace import ...``, with the ``tests`` folder
on ``sys.path``).

Definitions
-----------
*Module*: a file of the skcath package, named relative to it
(``online._estimator``, ``_validation``). A call is attributed to the
nearest function of the package below it on the stack; calls into other
libraries are skipped.

*Crossing*: a call of a package function whose nearest package caller is
in another module, ``caller_module.function -> callee_module.function``.

*Entering a family*: a crossing into ``_validation`` or one of the modules
it is split into (``_validation_columns``, ``_validation_runs``,
``_validation_target``) from a module outside them; such a family counts as
one module for the entries.

*Below*: module B is below module A on a path when the path calls from A
into B, directly or through other modules (a chain of crossings
``A -> ... -> B``). A crossing *re-enters* a module when it goes from B into
a module A that B is below: back up the path. A path without such a
crossing is layered: its modules and crossings form a directed graph
without a cycle, so that each module is only ever entered from above.

*Callback*: a crossing made by a solver module of :data:`CALLBACK_CALLERS`
(``backbones._lm``, the Levenberg-Marquardt loop) into a module already on
the call stack: the solver calls the objective it was given. Callbacks are
not recorded.
"""

from __future__ import annotations

import sys
from pathlib import Path

import skcath

PACKAGE_DIR = Path(skcath.__file__).resolve().parent
#: Modules whose calls back into a module on the stack are the callbacks of a solver.
CALLBACK_CALLERS = ("backbones._lm",)


def module_of(filename):
    """Module name of a file of the package, relative to it (``online._estimator``), or None."""
    try:
        relative = Path(filename).resolve().relative_to(PACKAGE_DIR)
    except ValueError:
        return None
    parts = list(relative.with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "skcath"


def in_family(module, family):
    """Whether ``module`` is ``family`` or one of the modules it is split into (``family_*``)."""
    return module == family or module.startswith(family + "_")


def _module_part(name):
    """``online._estimator`` of ``online._estimator.start``."""
    return name.rsplit(".", 1)[0]


class ModuleTracer:
    """Record the crossings between modules of the package during a call.

    Use as a context manager; afterwards :attr:`crossings` holds one
    ``(depth, caller, callee, on_stack)`` per crossing, where ``caller`` and
    ``callee`` are ``"module.function"``, ``depth`` is the number of
    modules on the module stack below the callee, and ``on_stack`` tells
    whether the callee's module is on that stack already (a re-entry that
    the call stack itself shows).
    """

    def __init__(self):
        self.crossings = []
        self._callers = []
        self._modules = {}

    def _module(self, code):
        filename = code.co_filename
        if filename not in self._modules:
            self._modules[filename] = module_of(filename)
        return self._modules[filename]

    def _package_caller(self, frame):
        """The nearest frame below ``frame`` that runs package code, or None."""
        frame = frame.f_back
        while frame is not None and self._module(frame.f_code) is None:
            frame = frame.f_back
        return frame

    def _module_stack(self, frame):
        """Modules of the package frames below ``frame``, bottom first, runs collapsed."""
        stack = []
        while frame is not None:
            module = self._module(frame.f_code)
            if module is not None and (not stack or stack[-1] != module):
                stack.append(module)
            frame = frame.f_back
        return stack[::-1]

    def _profile(self, frame, event, arg):
        if event != "call":
            return
        callee = self._module(frame.f_code)
        if callee is None:
            return
        caller_frame = self._package_caller(frame)
        if caller_frame is None:
            return
        caller = self._module(caller_frame.f_code)
        if caller == callee:
            return
        below = self._module_stack(caller_frame)
        if caller in CALLBACK_CALLERS and callee in below:
            return
        self.crossings.append((
            len(below),
            f"{caller}.{caller_frame.f_code.co_name}",
            f"{callee}.{frame.f_code.co_name}",
            callee in below,
        ))
        self._callers.append(caller_frame)  # kept alive: one frame, one visit

    def __enter__(self):
        sys.setprofile(self._profile)
        return self

    def __exit__(self, *exc):
        sys.setprofile(None)
        return False

    def entries(self, family):
        """The crossings into ``family`` (:func:`in_family`) from a module outside it."""
        return [(caller, callee) for _, caller, callee, _ in self.crossings
                if in_family(_module_part(callee), family)
                and not in_family(_module_part(caller), family)]

    def visits(self, family):
        """How many calls of functions outside ``family`` go into it (one count per calling call)."""
        return len({id(frame) for frame, (_, caller, callee, _) in zip(self._callers, self.crossings)
                    if in_family(_module_part(callee), family)
                    and not in_family(_module_part(caller), family)})

    def graph(self):
        """The modules each module calls into: ``{module: set of modules}``."""
        calls = {}
        for _, caller, callee, _ in self.crossings:
            calls.setdefault(_module_part(caller), set()).add(_module_part(callee))
        return calls

    def re_entries(self):
        """The crossings that go back up the path: into a module that the caller's module is below."""
        calls = self.graph()

        def reaches(start, goal):
            seen, todo = set(), [start]
            while todo:
                module = todo.pop()
                if module == goal:
                    return True
                if module not in seen:
                    seen.add(module)
                    todo.extend(calls.get(module, ()))
            return False

        return [(caller, callee) for _, caller, callee, _ in self.crossings
                if reaches(_module_part(callee), _module_part(caller))]

    def by_stage(self, family, top):
        """Crossings into ``family`` below each call that ``top`` makes into another module.

        Returns a list of ``(stage, n_calls, functions)``: ``stage`` is the
        crossing out of ``top`` (``"top.function -> other.function"``),
        ``functions`` the functions of ``family`` called below it from
        outside it, in order.
        """
        stages = []
        for _, caller, callee, _ in self.crossings:
            into = in_family(_module_part(callee), family)
            if _module_part(caller) == top:
                stages.append((f"{caller} -> {callee}", []))
            if into and not in_family(_module_part(caller), family) and stages:
                stages[-1][1].append(callee.rsplit(".", 1)[1])
        return [(stage, len(calls), calls) for stage, calls in stages if calls]
