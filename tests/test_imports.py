"""The import structure of the package: leaf modules, no circle, no needless deferred import.

The modules of ``skcath`` are read as text with :mod:`ast`, so these tests
see the imports as written rather than what happens to be loaded already.
An import at module level (also inside a module-level ``if`` or ``try``) is
an edge of the import graph; importing ``a.b.c`` runs the ``__init__`` of the
packages ``a.b`` too, so those are edges as well (except the importing
module's own packages, which Python has started to run before it).
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import skcath

PACKAGE_DIR = Path(skcath.__file__).parent

#: Optional dependencies (``pyproject.toml``) that a function may import
#: when it needs them, so that the package imports without them.
OPTIONAL = {
    "dask",
    "distributed",
    "llvmlite",  # numba's own code generator, installed with numba
    "matplotlib",
    "numba",
    "onnx",
    "onnxruntime",
    "pyarrow",
    "ray",
    "rosbags",
    "skops",
}

#: Modules that must not import any other skcath module.
LEAVES = ("skcath._format", "skcath._version", "skcath.exceptions", "skcath._medians")


def _modules():
    """Module name -> (path, is_package) for every module of the package."""
    out = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, is_package)
    return out


MODULES = _modules()


def _module_level(body):
    """Statements run when the module is imported (module-level ``if``/``try`` included)."""
    for node in body:
        yield node
        if isinstance(node, (ast.If, ast.Try)):
            yield from _module_level(node.body)
            yield from _module_level(node.orelse)
            for handler in getattr(node, "handlers", []):
                yield from _module_level(handler.body)
            yield from _module_level(getattr(node, "finalbody", []))


def _targets(node, name):
    """Absolute names of what the import statement ``node`` in module ``name`` imports."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if node.level:
        _, is_package = MODULES[name]
        parts = name.split(".") if is_package else name.split(".")[:-1]
        parts = parts[: len(parts) - node.level + 1]
        base = ".".join(parts + ([node.module] if node.module else []))
    else:
        base = node.module
    # "from . import x" imports the submodule x when there is one
    return [base] + [f"{base}.{alias.name}" for alias in node.names
                     if f"{base}.{alias.name}" in MODULES]


def _with_packages(target):
    """``target`` and the packages above it, as far as they are skcath modules."""
    parts = target.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)
            if ".".join(parts[:i]) in MODULES]


def _tree(name):
    return ast.parse(MODULES[name][0].read_text(encoding="utf-8"))


def _edges(name, statements):
    """skcath modules that the import statements run, the importing module's packages left out."""
    parts = name.split(".")
    own = {".".join(parts[:i]) for i in range(1, len(parts) + 1)}
    out = set()
    for node in statements:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            for target in _targets(node, name):
                out.update(m for m in _with_packages(target) if m not in own)
    return out


def _import_graph():
    return {name: _edges(name, _module_level(_tree(name).body)) for name in MODULES}


def _reachable(graph, start):
    seen, todo = set(), [start]
    while todo:
        for nxt in graph[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def _cycle(graph):
    """One import circle as a list of modules, or None."""
    state = {}

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt, path + [nxt])
                if found:
                    return found
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state:
            found = visit(node, [node])
            if found:
                return found
    return None


def _deferred_imports(name):
    """Import statements inside functions and methods of module ``name``."""
    for node in ast.walk(_tree(name)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for inner in ast.walk(node):
                if isinstance(inner, (ast.Import, ast.ImportFrom)):
                    yield inner


def _optional_behind(graph, module):
    """Whether importing skcath ``module`` imports an optional dependency at module level."""
    for name in {module} | _reachable(graph, module):
        for node in _module_level(_tree(name).body):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                if any(t.split(".")[0] in OPTIONAL for t in _targets(node, name)):
                    return True
    return False


def test_the_graph_reader_sees_the_known_edges():
    graph = _import_graph()
    assert "skcath._validation" in graph["skcath"]
    assert "skcath.residuals._estimators" in graph["skcath.residuals"]
    # importing skcath.backbones._pcc from elsewhere runs skcath/backbones/__init__.py
    assert "skcath.backbones" in graph["skcath.online._estimator"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle():
    cycle = _cycle(_import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle)


@pytest.mark.parametrize("leaf", LEAVES)
def test_leaf_modules_import_nothing_from_skcath(leaf):
    assert _import_graph()[leaf] == set()
    for node in ast.walk(_tree(leaf)):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            assert not any(t.startswith("skcath") for t in _targets(node, leaf)), ast.unparse(node)


def test_deferred_imports_only_for_optional_dependencies_or_circles():
    """An import inside a function needs an optional dependency or an import circle behind it."""
    graph = _import_graph()
    needless = []
    for name in MODULES:
        for node in _deferred_imports(name):
            targets = _targets(node, name)
            if len(targets) > 1 and len(targets) == len(node.names) + 1:
                targets = targets[1:]  # "from pkg import sub1, sub2": only the submodules
            for target in targets:
                if target.split(".")[0] in OPTIONAL:
                    continue
                if target in MODULES:
                    circle = name in _reachable(graph, target)
                    if circle or _optional_behind(graph, target):
                        continue
                needless.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    assert not needless, "\n".join(needless)


def test_every_module_imports():
    """Each module imports on its own, in a fresh interpreter (so that no optional
    dependency is left loaded in this one); a module built on an optional
    dependency that is not installed is passed over."""
    script = (
        "import importlib, sys\n"
        f"optional = {sorted(OPTIONAL)!r}\n"
        "for name in sys.argv[1:]:\n"
        "    try:\n"
        "        importlib.import_module(name)\n"
        "    except ImportError as exc:\n"
        "        if not (exc.name and exc.name.split('.')[0] in optional):\n"
        "            raise\n"
    )
    names = [name for name in MODULES if not name.endswith("__main__")]
    result = subprocess.run([sys.executable, "-c", script, *names], capture_output=True,
                            text=True, cwd=PACKAGE_DIR.parent)
    assert result.returncode == 0, result.stderr


def test_exceptions_are_the_same_classes_everywhere():
    from skcath import exceptions, persist

    assert set(exceptions.__all__) == {
        "FileSuffixWarning", "GroupsNotUsedWarning", "InconsistentVersionWarning",
        "IncompatibleVersionError", "MotorLimitWarning", "PickledFileError",
        "PipelineChangedWarning", "SampleRateWarning",
        "TruncatedFileWarning",
    }
    assert issubclass(exceptions.MotorLimitWarning, UserWarning)
    assert issubclass(exceptions.SampleRateWarning, UserWarning)
    assert issubclass(exceptions.FileSuffixWarning, UserWarning)
    assert issubclass(exceptions.PipelineChangedWarning, UserWarning)
    assert issubclass(exceptions.GroupsNotUsedWarning, UserWarning)
    assert persist.InconsistentVersionWarning is exceptions.InconsistentVersionWarning
    assert persist.IncompatibleVersionError is exceptions.IncompatibleVersionError
    assert persist.PickledFileError is exceptions.PickledFileError
    assert issubclass(exceptions.PickledFileError, ValueError)
    assert issubclass(exceptions.InconsistentVersionWarning, UserWarning)
    assert issubclass(exceptions.IncompatibleVersionError, ValueError)
    from skcath import _version

    assert skcath.__version__ == _version.__version__ == _version.current_version()
