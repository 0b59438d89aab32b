"""Checks of the package's layout: short functions, and benchmarks that use the public API.

These read the source as text (with :mod:`ast`); nothing here imports the
benchmark scripts.
"""

import ast
import io
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "skcath"
BENCHMARKS = ROOT / "benchmarks"

#: Scripts of ``benchmarks/`` that diagnose what no public function returns,
#: and the private modules each of them may read: the simulator's own truth
#: (offsets, transmission output, wind-up of every sample), and the pieces of
#: the compiled streaming step timed one by one.
DIAGNOSES = {
    "diagnose_backbone_error.py": {"skcath.datasets._benchmark", "skcath.datasets._simulator"},
    "_streaming_breakdown.py": {"skcath._kernel", "skcath.online", "skcath.online._jit",
                                "skcath.online._layout"},
}

#: Longest function body allowed in the package, in lines of code (blank,
#: comment and docstring lines not counted).
MAX_FUNCTION_LINES = 80


def _docstring_lines(tree):
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (body and isinstance(body[0], ast.Expr)
                    and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                lines.update(range(body[0].lineno, body[0].end_lineno + 1))
    return lines


def _code_lines(source):
    """Line numbers that hold code: no blank, comment-only or docstring line."""
    skip = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT,
            tokenize.DEDENT, tokenize.ENDMARKER}
    lines = set()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type not in skip:
            lines.update(range(token.start[0], token.end[0] + 1))
    return lines - _docstring_lines(ast.parse(source))


def function_lengths(path):
    """``(name, first line, lines of code)`` of every function in a file."""
    source = path.read_text(encoding="utf-8")
    code = _code_lines(source)
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = sum(1 for line in range(node.lineno, node.end_lineno + 1) if line in code)
            yield node.name, node.lineno, n


def test_line_counter_skips_docstrings_comments_and_blank_lines(tmp_path):
    path = tmp_path / "m.py"
    path.write_text('def f(x):\n    """Doc.\n\n    More.\n    """\n    # note\n\n    y = (x +\n         1)\n    return y\n')
    assert list(function_lengths(path)) == [("f", 1, 4)]


def test_no_long_function_in_the_package():
    long = [
        f"{path.relative_to(ROOT)}:{line} {name} ({n} lines of code)"
        for path in sorted(PACKAGE.rglob("*.py"))
        for name, line, n in function_lengths(path)
        if n > MAX_FUNCTION_LINES
    ]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines of code: {long}"


def _private_imports(path):
    """Imports of private skcath modules or names in one script (those of a diagnosis left out)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    allowed = DIAGNOSES.get(path.name, set())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in allowed:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "skcath":
            parts = node.module.split(".")
            names = [alias.name for alias in node.names]
            if any(p.startswith("_") for p in parts) or any(n.startswith("_") for n in names):
                found.append(f"{path.name}:{node.lineno} from {node.module} import {', '.join(names)}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "skcath" and any(p.startswith("_") for p in parts):
                    found.append(f"{path.name}:{node.lineno} import {alias.name}")
    return found


@pytest.mark.parametrize("path", sorted(BENCHMARKS.glob("*.py")), ids=lambda p: p.name)
def test_benchmarks_import_only_public_names(path):
    assert _private_imports(path) == []


def test_diagnoses_exist_and_read_only_their_modules(tmp_path):
    for name in DIAGNOSES:
        assert (BENCHMARKS / name).is_file(), name
    # another private module in a diagnosis is still found
    path = tmp_path / "diagnose_backbone_error.py"
    path.write_text("from skcath.datasets._simulator import _lag\nfrom skcath.backbones._pi import pi_step\n")
    assert _private_imports(path) == ["diagnose_backbone_error.py:2 from skcath.backbones._pi import pi_step"]


def test_public_names_of_benchmark_imports_are_exported():
    import importlib
    import importlib.util

    missing = []
    for path in sorted(BENCHMARKS.glob("*.py")):
        allowed = DIAGNOSES.get(path.name, set())
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module in allowed:
                continue
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "skcath":
                module = importlib.import_module(node.module)
                exported = set(getattr(module, "__all__", ()))
                for alias in node.names:
                    # a submodule (``from skcath import persist``) is public by its own name
                    submodule = hasattr(module, "__path__") and (
                        importlib.util.find_spec(f"{node.module}.{alias.name}") is not None
                    )
                    if alias.name not in exported and not submodule:
                        missing.append(f"{path.name}:{node.lineno} {node.module}.{alias.name}")
    assert not missing, f"names not in their module's __all__: {missing}"


def _loads_a_benchmark_script(path):
    """Whether a test file loads a file of ``benchmarks/`` as a module or runs it."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in {"spec_from_file_location", "run_path", "import_module"}:
                strings = [c.value for c in ast.walk(node)
                           if isinstance(c, ast.Constant) and isinstance(c.value, str)]
                if any("benchmarks" in s or s.startswith("bench_") for s in strings):
                    return True
    return False


def test_tests_do_not_import_benchmark_scripts():
    offenders = [path.name for path in sorted((ROOT / "tests").glob("*.py"))
                 if _loads_a_benchmark_script(path)]
    assert offenders == []


def test_the_benchmark_loader_check_sees_a_loader(tmp_path):
    path = tmp_path / "test_x.py"
    path.write_text('import importlib.util\n'
                    'spec = importlib.util.spec_from_file_location("b", "benchmarks/bench_x.py")\n')
    assert _loads_a_benchmark_script(path)


def test_slow_marks_name_existing_tests():
    """Every test marked slow by id in conftest.py exists: its file, function and example."""
    from conftest import SLOW

    missing = []
    for test_id, covered_by in SLOW.items():
        assert covered_by, f"{test_id}: no default test named for its behaviour"
        file_name, name = test_id.split("::")
        function, _, params = name.partition("[")
        path = ROOT / "tests" / file_name
        defined = path.is_file() and any(
            isinstance(node, ast.FunctionDef) and node.name == function
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        )
        if not defined:
            missing.append(test_id)
        elif function == "test_example_runs" and not list((ROOT / "examples").rglob(params[:-1])):
            missing.append(test_id)
    assert missing == []
