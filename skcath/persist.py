"""Save and load fitted estimators, with the versions they were fitted under.

A file written by :func:`save` is a zip archive of two members:

``skcath.json``
    The versions of skcath, scikit-learn, torch, skorch, numpy and Python that
    wrote the file, the payload format and the estimator's class.
``estimator.joblib`` or ``estimator.skops``
    The estimator, serialized with :func:`joblib.dump` or :func:`skops.io.dump`.

:func:`load` reads the versions first and refuses a file written by an
incompatible skcath version (see :func:`is_compatible_version`) before it
unpickles anything, so a changed class layout gives a clear message instead of
an obscure unpickling error.

Estimators pickled directly (``pickle.dump``, ``joblib.dump``) carry the skcath
version too: :class:`~skcath._base.RecordingsMixin` stores it in the pickled
state and warns with :class:`InconsistentVersionWarning` when it differs from
the running version on unpickling.
"""

from __future__ import annotations

import io
import json
import os
import platform
import re
import warnings
import zipfile
from importlib import metadata

from ._base import _current_version

__all__ = [
    "FORMATS",
    "InconsistentVersionWarning",
    "IncompatibleVersionError",
    "get_untrusted_types",
    "is_compatible_version",
    "load",
    "read_versions",
    "save",
]

#: Serialization formats of the estimator inside a saved file.
FORMATS = ("joblib", "skops")

_HEADER = "skcath.json"
_PAYLOAD = {"joblib": "estimator.joblib", "skops": "estimator.skops"}
_FILE_FORMAT = 1
_RECORDED = ("scikit-learn", "torch", "skorch", "numpy", "joblib", "skops")


class InconsistentVersionWarning(UserWarning):
    """An estimator is unpickled under another skcath version than it was pickled with.

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

    Raised by :func:`load`; ``allow_version_mismatch=True`` loads the file anyway.
    """


def _release(version: str) -> tuple[int, int]:
    """(major, minor) of a PEP 440 version string (a missing minor counts as 0)."""
    match = re.match(r"\s*v?(\d+)(?:\.(\d+))?", str(version))
    if match is None:
        raise ValueError(f"cannot parse the skcath version {version!r}")
    return int(match[1]), int(match[2] or 0)


def is_compatible_version(saved: str, running: str | None = None) -> bool:
    """Whether an estimator saved by skcath ``saved`` may be loaded by ``running``.

    The rule follows semantic versioning: from 1.0 on, versions with the same
    major number are compatible; before 1.0 (``0.x``), every minor release may
    change the fitted attributes, so versions must share major *and* minor
    numbers. Patch releases and pre-/post-/dev-releases of one release line are
    compatible: ``0.1.0.dev0``, ``0.1.0`` and ``0.1.3`` are; ``0.1.2`` and
    ``0.2.0`` are not; ``1.2.0`` and ``1.5.1`` are; ``1.9.0`` and ``2.0.0`` are not.

    Parameters
    ----------
    saved : str
        skcath version recorded in the saved file.
    running : str, default=None
        skcath version that loads it; None means the installed ``skcath.__version__``.

    Returns
    -------
    compatible : bool
    """
    running = _current_version() if running is None else running
    a, b = _release(saved), _release(running)
    if a[0] != b[0]:
        return False
    return a[0] != 0 or a[1] == b[1]


def _versions() -> dict:
    out = {"skcath": _current_version(), "python": platform.python_version()}
    for name in _RECORDED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def save(estimator, path, *, format="joblib", compress=3) -> None:
    """Save a (fitted) estimator with the versions of skcath and its dependencies.

    Parameters
    ----------
    estimator : object
        Any estimator or pipeline; skcath estimators need not be fitted.
    path : str or os.PathLike
        File to write (overwritten if it exists); ``.skcath`` is a good suffix.
    format : {"joblib", "skops"}, default="joblib"
        Serializer of the estimator. ``"joblib"`` handles every estimator;
        loading it runs arbitrary code from the file, so load only files you
        trust. ``"skops"`` needs the ``skops`` package and lets :func:`load`
        check the types in the file against a list of trusted ones (see
        :func:`get_untrusted_types`); it handles backbones and
        :class:`~skcath.residuals.NoResidual` but not the residual learners,
        whose torch state skops cannot store (see ``docs/persistence.rst``).
    compress : int, default=3
        zlib level (0-9) of the archive members.

    Raises
    ------
    ValueError
        ``format="skops"`` and the estimator holds objects skops cannot store.

    See Also
    --------
    load : Read the file back, checking the versions.
    """
    if format not in FORMATS:
        raise ValueError(f"format: expected one of {list(FORMATS)}, got {format!r}")
    if not (isinstance(compress, int) and 0 <= compress <= 9):
        raise ValueError(f"compress: expected an int in [0, 9], got {compress!r}")
    if format == "joblib":
        import joblib

        buffer = io.BytesIO()
        joblib.dump(estimator, buffer)
        payload = buffer.getvalue()
    else:
        import skops.io as sio

        try:
            payload = sio.dumps(estimator)
        except (TypeError, RuntimeError) as exc:
            raise ValueError(
                f"format='skops' cannot serialize this {type(estimator).__name__}: skops stores "
                "neither torch tensors (the residual learners' networks and optimizer state) nor "
                "pandas DataFrames. Use format='joblib'."
            ) from exc
    header = {
        "file_format": _FILE_FORMAT,
        "format": format,
        "estimator": f"{type(estimator).__module__}.{type(estimator).__qualname__}",
        "versions": _versions(),
    }
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=compress) as zf:
        zf.writestr(_HEADER, json.dumps(header, indent=2))
        zf.writestr(_PAYLOAD[format], payload)


def _open(path):
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise ValueError(f"{os.fspath(path)!r} is not a file written by skcath.persist.save") from exc
    try:
        header = json.loads(zf.read(_HEADER))
    except KeyError as exc:
        zf.close()
        raise ValueError(
            f"{os.fspath(path)!r} has no {_HEADER}: it was not written by skcath.persist.save"
        ) from exc
    if header.get("file_format") != _FILE_FORMAT or header.get("format") not in FORMATS:
        zf.close()
        raise ValueError(
            f"{os.fspath(path)!r}: unknown file layout {header.get('file_format')!r} / format "
            f"{header.get('format')!r}; it was written by a newer skcath?"
        )
    return zf, header


def read_versions(path) -> dict:
    """The header of a saved file, without loading the estimator.

    Parameters
    ----------
    path : str or os.PathLike
        File written by :func:`save`.

    Returns
    -------
    header : dict
        ``format`` (``"joblib"`` or ``"skops"``), ``estimator`` (its class) and
        ``versions`` (package name to version string, None if not installed).
    """
    zf, header = _open(path)
    zf.close()
    return header


def get_untrusted_types(path) -> list[str]:
    """Types in a skops-format file that skops does not trust by default.

    Pass the ones you trust to ``load(path, trusted=...)``.

    Parameters
    ----------
    path : str or os.PathLike
        File written by ``save(..., format="skops")``.

    Returns
    -------
    types : list of str
        Fully qualified type names.
    """
    import skops.io as sio

    zf, header = _open(path)
    with zf:
        if header["format"] != "skops":
            raise ValueError(
                f"{os.fspath(path)!r} holds a {header['format']} payload: only the skops format "
                "has a list of types to trust (a joblib file is trusted entirely or not at all)"
            )
        return sio.get_untrusted_types(data=zf.read(_PAYLOAD["skops"]))


def load(path, *, trusted=None, allow_version_mismatch=False):
    """Load an estimator saved by :func:`save`, after checking the skcath version.

    Parameters
    ----------
    path : str or os.PathLike
        File written by :func:`save`.
    trusted : list of str, default=None
        skops format only: types to trust beyond skops' defaults, as listed by
        :func:`get_untrusted_types`; loading fails if the file holds any other
        untrusted type. Must be None for a joblib file, whose loading runs
        arbitrary code from the file: load only joblib files you trust.
    allow_version_mismatch : bool, default=False
        Load a file written by an incompatible skcath version anyway (with an
        :class:`InconsistentVersionWarning`) instead of raising.

    Returns
    -------
    estimator : object

    Raises
    ------
    IncompatibleVersionError
        The file was written by a skcath version that :func:`is_compatible_version`
        rejects, and ``allow_version_mismatch`` is False.

    Warns
    -----
    InconsistentVersionWarning
        The file was written by another skcath version (compatible, or allowed
        by ``allow_version_mismatch``).
    """
    zf, header = _open(path)
    with zf:
        fmt = header["format"]
        saved = header["versions"]["skcath"]
        running = _current_version()
        name = header["estimator"].rsplit(".", 1)[-1]
        if not is_compatible_version(saved, running) and not allow_version_mismatch:
            raise IncompatibleVersionError(
                f"{os.fspath(path)!r} holds a {name} saved with skcath {saved}, which the running "
                f"skcath {running} cannot load (versions 0.x must share major and minor numbers, "
                f"later ones the major number). Refit the estimator with skcath {running}, or "
                f"install skcath {saved} to use it, or pass allow_version_mismatch=True to load "
                "it anyway at your own risk."
            )
        if trusted is not None and fmt != "skops":
            raise ValueError(
                f"trusted: only for skops-format files; {os.fspath(path)!r} holds a {fmt} payload"
            )
        payload = zf.read(_PAYLOAD[fmt])
    with warnings.catch_warnings():
        # one warning from here instead of one per unpickled skcath estimator
        warnings.simplefilter("ignore", InconsistentVersionWarning)
        if fmt == "joblib":
            import joblib

            estimator = joblib.load(io.BytesIO(payload))
        else:
            import skops.io as sio

            estimator = sio.loads(payload, trusted=trusted)
    if saved != running:
        warnings.warn(
            InconsistentVersionWarning(
                estimator_name=name, original_version=saved, current_version=running
            ),
            stacklevel=2,
        )
    return estimator
