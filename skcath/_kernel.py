"""Scalar kernels that run as Python or compiled by numba, with numba optional.

A kernel is a plain Python function on floats and flat arrays, written in
the subset of Python that numba compiles (``math``, loops, indexing). The
package writes each equation once as such a kernel; where numba can be
imported, the batch evaluations and the streaming engine compile it,
otherwise the same function runs as Python. numba is imported only when a
compiled kernel is first needed, never when the package is imported.

Three decorators declare what numba needs to know about a function that
compiled code calls:

* :func:`kernel`: numba compiles the function as it is;
* :func:`compiled_as`: numba compiles another implementation in its place.
  The Python function stays what Python runs (e.g. one numpy call on a
  vector), the implementation is what compiled code runs (e.g. the loop that
  the compiler vectorises); both compute the same thing.
* :func:`compiled_by_dtype`: as :func:`compiled_as`, with one
  implementation for float64 and one for float32, chosen by the type of the
  first argument.

The declarations take effect when numba is loaded (:func:`load_numba`).

Compiled functions are cached on disk. numba's cache recognises a changed
source by the file of the function it compiled, not by the files of the
kernels that function calls, so a cache kept next to the sources could hand
an upgraded or edited package the machine code of its old kernels. The
cache therefore lives in a folder of its own per set of kernel sources
(:func:`cache_folder`): under ``$NUMBA_CACHE_DIR`` when it is set, else
under the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``), in
``skcath-<version>/<digest of the kernels' source files>``.
"""

from __future__ import annotations

import bisect as _bisect
import hashlib
import inspect
import os
import threading
from pathlib import Path

import numpy as np

from ._version import __version__

__all__ = [
    "JIT_OPTIONS",
    "bisect_right",
    "cache_folder",
    "compiled",
    "compiled_as",
    "compiled_by_dtype",
    "evaluate_rows",
    "float_bits",
    "fma",
    "kernel",
    "load_numba",
    "numba_enabled",
    "offsets",
    "row_loop",
    "tip_kernel",
    "with_bits",
]

#: Options of every compiled kernel: no Python objects, the GIL released, and
#: numpy's error model (no zero-division checks: a kernel's divisors are
#: never zero, and a check would keep the compiler from vectorising loops).
JIT_OPTIONS = {"nogil": True, "error_model": "numpy"}

_lock = threading.RLock()
_declared = []  # (function, compiled implementation), in order of declaration
_state = {"numba": None, "registered": 0}
_compiled = {}


def kernel(func):
    """Declare ``func`` a kernel that numba compiles as it is; returns ``func``."""
    _declare(func, func)
    return func


def offsets(*sizes):
    """Offsets of consecutive blocks of the given sizes in a flat array, then its size.

    ``offsets(2, 1, 4)`` is ``(0, 2, 3, 7)``: the named layouts of the
    packed arrays are written this way, block sizes in order.
    """
    at = [0]
    for size in sizes:
        at.append(at[-1] + size)
    return tuple(at)


_TIP_KERNEL_SECTIONS = """

    Parameters
    ----------
    theta : ndarray or list of float
        The packed parameters, :meth:`{params}.pack`.
    q1, q2 : float
        Motor angles (deg).

    Returns
    -------
    x, y, z : float
        Tip position in the base frame (mm).
    """


def tip_kernel(params_class):
    """Declare a backbone's tip kernel ``(theta, q1, q2) -> (x, y, z)``, as :func:`kernel`.

    Appends the sections common to the tip kernels to the docstring;
    ``params_class`` names the parameter class whose ``pack`` gives ``theta``.
    """

    def declare(func):
        func.__doc__ = func.__doc__.rstrip() + _TIP_KERNEL_SECTIONS.format(params=params_class)
        return kernel(func)

    return declare


def compiled_as(implementation):
    """Declare that compiled code runs ``implementation`` in place of the decorated function.

    Parameters
    ----------
    implementation : callable
        A function with the same arguments, in the subset of Python that
        numba compiles.

    Returns
    -------
    decorator : callable
        Returns the decorated function unchanged (what Python runs).
    """

    def declare(func):
        _declare(func, implementation)
        return func

    return declare


def compiled_by_dtype(float64, float32):
    """Declare the implementations compiled code runs in place of the decorated function, by dtype.

    As :func:`compiled_as`, the implementation chosen by the type of the
    first argument: ``float32`` for a float32 number or array, ``float64``
    otherwise.
    """

    def declare(func):
        _declare(func, {"float64": float64, "float32": float32})
        return func

    return declare


def _declare(func, implementation):
    with _lock:
        _declared.append((func, implementation))
        if _state["numba"] is not None:
            _register_declared()


def _register_declared():
    """Register the declarations made since the last call with numba."""
    from numba.extending import overload

    for func, implementation in _declared[_state["registered"] :]:

        def typer(*args, _implementation=implementation, **kwargs):
            if isinstance(_implementation, dict):
                kind = getattr(args[0], "dtype", args[0])
                return _implementation["float32" if str(kind) == "float32" else "float64"]
            return _implementation

        # a primitive's loops are inlined where they are called, as if written there
        inline = "never" if implementation is func else "always"
        overload(func, jit_options=JIT_OPTIONS, strict=False, inline=inline)(typer)
    _state["registered"] = len(_declared)


def numba_enabled():
    """Whether numba can be imported and compiles (``NUMBA_DISABLE_JIT`` unset)."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    try:
        load_numba()
    except ImportError:
        return False
    return True


def load_numba():
    """numba, with every declared kernel registered.

    Returns
    -------
    numba : module

    Raises
    ------
    ImportError
        Where numba cannot be imported.
    """
    with _lock:
        if _state["numba"] is None:
            import numba

            _register_fma()
            _register_bits()
            _state["numba"] = numba
        _register_declared()
        return _state["numba"]


def fma(a, b, c):
    """``a * b + c``, rounded once where compiled (the processor's fused multiply-add).

    Python rounds the product and the sum each. Compiled code computes the
    exact ``a * b + c`` rounded once, in float64 if any argument is float64,
    else in float32, as one instruction where the processor has one; loops
    of it vectorise.
    """
    return a * b + c


def _register_fma():
    """Declare the compiled :func:`fma`: LLVM's ``llvm.fma`` on the arguments' common type."""
    from numba.core import types
    from numba.extending import intrinsic, overload

    @intrinsic
    def fused(typingctx, a, b, c):
        kind = types.float64 if types.float64 in (a, b, c) else types.float32

        def codegen(context, builder, signature, args):
            x, y, z = (context.cast(builder, v, t, kind) for v, t in zip(args, signature.args))
            return builder.fma(x, y, z)

        return kind(a, b, c), codegen

    def typer(a, b, c):
        return lambda a, b, c: fused(a, b, c)

    overload(fma, jit_options=JIT_OPTIONS, inline="always")(typer)


def float_bits(x):
    """The bits of the float ``x`` as a signed integer of its width: int32 for float32, else int64.

    Compiled code reinterprets the register (no instruction); loops of it
    vectorise.
    """
    if isinstance(x, np.float32):
        return int(x.view(np.int32))
    return int(np.float64(x).view(np.int64))


def with_bits(i, x):
    """The float of the type of ``x`` whose bits are the low bits of the integer ``i``.

    The inverse of :func:`float_bits`: ``with_bits(float_bits(x), x) == x``.
    """
    if isinstance(x, np.float32):
        return np.int64(i).astype(np.int32).view(np.float32)
    return np.int64(i).view(np.float64)


def _register_bits():
    """Declare the compiled :func:`float_bits` and :func:`with_bits`: LLVM's bit casts."""
    from llvmlite import ir
    from numba.core import types
    from numba.extending import intrinsic, overload

    @intrinsic
    def bits_of(typingctx, x):
        kind = types.int32 if x == types.float32 else types.int64

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], ir.IntType(kind.bitwidth))

        return kind(x), codegen

    @intrinsic
    def float_of(typingctx, i, x):
        def codegen(context, builder, signature, args):
            width = x.bitwidth
            v = context.cast(builder, args[0], i, types.int64)
            if width < 64:
                v = builder.trunc(v, ir.IntType(width))
            return builder.bitcast(v, context.get_value_type(x))

        return x(i, x), codegen

    overload(float_bits, jit_options=JIT_OPTIONS, inline="always")(
        lambda x: lambda x: bits_of(x))
    overload(with_bits, jit_options=JIT_OPTIONS, inline="always")(
        lambda i, x: lambda i, x: float_of(i, x))


def _source_files(func):
    """Source files of ``func`` and of every kernel declared so far, sorted."""
    functions = [func]
    for declared, implementation in _declared:
        functions.append(declared)
        functions.extend(implementation.values() if isinstance(implementation, dict)
                         else [implementation])
    files = {inspect.getsourcefile(inspect.unwrap(f)) for f in functions}
    return sorted(Path(f) for f in files if f)


def cache_folder(func):
    """Folder of numba's cache for ``func``: one per version and kernel sources.

    Parameters
    ----------
    func : callable
        A kernel, or a loop calling kernels.

    Returns
    -------
    folder : pathlib.Path
        ``<base>/skcath-<version>/<digest>``, where ``<base>`` is
        ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/numba`` (default
        ``~/.cache/numba``), and ``<digest>`` the first 16 hex digits of the
        sha1 of the names and contents of :func:`_source_files`. An edited
        kernel changes the digest, so stale machine code is never loaded.
    """
    digest = hashlib.sha1()
    for path in _source_files(func):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"),
        "numba",
    )
    return Path(base) / f"skcath-{__version__}" / digest.hexdigest()[:16]


def compiled(func):
    """``func`` compiled by numba (cached on disk), or None where numba is not available.

    Compiled once per process (loaded from the cache, :func:`cache_folder`,
    when a previous process compiled the same sources) and kept.
    """
    with _lock:
        if func not in _compiled:
            _compiled[func] = _compile(func) if numba_enabled() else None
        return _compiled[func]


def _compile(func):
    """numba's dispatcher of ``func``, its cache in :func:`cache_folder`.

    numba reads its cache folder when the dispatcher is made, from
    ``numba.config.CACHE_DIR``; it is set for that moment only.
    """
    numba = load_numba()
    folder = cache_folder(func)
    previous = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(folder)
    try:
        return numba.njit(cache=True, **JIT_OPTIONS)(func)
    finally:
        numba.config.CACHE_DIR = previous


def row_loop(tip):
    """A loop evaluating the tip kernel ``tip(theta, q1, q2) -> (x, y, z)`` on every row.

    The loop reads the motor angles from ``q1``, ``q2`` and writes the
    coordinates into ``x``, ``y``, ``z``: arrays when compiled, lists when run
    as Python (where list items are faster than array items).
    """

    def loop(theta, q1, q2, x, y, z):
        for i in range(len(q1)):
            x[i], y[i], z[i] = tip(theta, q1[i], q2[i])

    loop.__doc__ = f"Rows of :func:`{tip.__name__}`."
    return loop


def evaluate_rows(loop, theta, q):
    """Tips of every row of ``q`` by a :func:`row_loop`, compiled where numba is available.

    Parameters
    ----------
    loop : callable
        The result of :func:`row_loop`.
    theta : ndarray of shape (n_theta,)
        Packed parameters of the kernel (float64).
    q : ndarray of shape (n, 2)
        Motor angles (deg), float64.

    Returns
    -------
    tips : ndarray of shape (n, 3)
    """
    n = q.shape[0]
    fast = compiled(loop)
    if fast is not None:
        x, y, z = np.empty(n), np.empty(n), np.empty(n)
        fast(theta, np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]), x, y, z)
    else:
        x, y, z = [0.0] * n, [0.0] * n, [0.0] * n
        loop(theta.tolist(), q[:, 0].tolist(), q[:, 1].tolist(), x, y, z)
    return np.column_stack([x, y, z])


def _bisect_right_compiled(a, x, lo, hi):
    while lo < hi:
        mid = (lo + hi) // 2
        if x < a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


@compiled_as(_bisect_right_compiled)
def bisect_right(a, x, lo, hi):
    """Index where ``x`` would be inserted in the sorted ``a[lo:hi]``, after equal items.

    As :func:`bisect.bisect_right`, which Python runs; compiled code runs the
    same binary search as a loop.
    """
    return _bisect.bisect_right(a, x, lo, hi)
