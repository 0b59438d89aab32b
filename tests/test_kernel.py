"""The kernel machinery of ``skcath._kernel``: where numba's cache of compiled kernels lives."""

from pathlib import Path

from skcath import _kernel
from skcath._version import __version__
from skcath.backbones import pcc_kernel


def test_cache_folder_follows_the_kernel_sources(tmp_path, monkeypatch):
    """An edited kernel source gets another cache folder: stale machine code is never loaded."""
    source = tmp_path / "kernels.py"
    source.write_text("def tip(theta, q1, q2):\n    return q1, q2, 0.0\n")
    monkeypatch.setattr(_kernel, "_source_files", lambda func: [source])
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    before = _kernel.cache_folder(pcc_kernel)
    assert before.parent == tmp_path / "cache" / f"skcath-{__version__}"
    assert _kernel.cache_folder(pcc_kernel) == before
    source.write_text("def tip(theta, q1, q2):\n    return q2, q1, 0.0\n")
    assert _kernel.cache_folder(pcc_kernel) != before


def test_cache_folder_without_numba_cache_dir_is_in_the_user_cache(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    folder = _kernel.cache_folder(pcc_kernel)
    assert folder.parent == tmp_path / "numba" / f"skcath-{__version__}"


def test_kernel_sources_include_the_function_and_the_declared_kernels():
    files = _kernel._source_files(pcc_kernel)
    assert Path(_kernel.__file__) in files  # bisect_right is declared there
    assert any(f.name == "_pcc.py" for f in files)
    assert files == sorted(files)
