"""Save and load fitted estimators, with the versions they were fitted under.

A file written by :func:`save` (suffix ``.skcath``) is a zip archive of two
members:

``skcath.json``
    The versions of skcath, scikit-learn, torch, skorch, numpy and Python that
    wrote the file, the payload format and the estimator's class.
``estimator.joblib`` or ``estimator.skops``
    The estimator, serialized with :func:`joblib.dump` or :func:`skops.io.dump`.

:func:`load` reads the versions first and refuses a file written by an
incompatible skcath version (see :func:`is_compatible_version`) before it
deserializes anything, so a changed class layout gives a clear message instead
of an obscure unpickling error. A file that is not such an archive, or whose
header is damaged, raises a ``ValueError`` naming the file and the problem.

The skops format, the default, stores no pickle at all: the residual
learners, whose torch state skops cannot store, go into it as plain arrays
and parameters (:mod:`skcath._torch_state`), a started
:class:`~skcath.online.OnlineEstimator` as its plain state
(:mod:`skcath.online._state`), and both are built again on loading. Loading
builds only skcath's own classes (:data:`TRUSTED_TYPES`), skops' defaults and
the types the caller names. A joblib file runs code from the file when it is
loaded, so :func:`load` refuses one unless ``allow_pickle=True``.

Estimators pickled directly (``pickle.dump``, ``joblib.dump``) carry the skcath
version too: :class:`~skcath._base.RecordingsMixin` stores it in the pickled
state and warns with :class:`~skcath.exceptions.InconsistentVersionWarning`
when it differs from the running version on unpickling.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import platform
import re
import warnings
import zipfile
import zlib
from importlib import metadata
from pathlib import Path

import joblib
from sklearn.utils._param_validation import validate_params

from ._torch_state import from_plain, to_plain
from ._trust import check_schema, default_trusted, read_schema
from ._version import current_version

# the version warning and error, public here too (their home is skcath.exceptions)
from .exceptions import (
    FileSuffixWarning,
    IncompatibleVersionError,
    InconsistentVersionWarning,
    PickledFileError,
)

__all__ = [
    "FORMATS",
    "SUFFIX",
    "TRUSTED_TYPES",
    "InconsistentVersionWarning",
    "IncompatibleVersionError",
    "PickledFileError",
    "get_untrusted_types",
    "is_compatible_version",
    "load",
    "read_versions",
    "save",
]

#: Serialization formats of the estimator inside a saved file.
FORMATS = ("joblib", "skops")

#: Suffix of the files written by :func:`save`.
SUFFIX = ".skcath"

#: skcath's types that :func:`load` trusts in a skops-format file, beyond
#: skops' defaults: the classes :func:`save` writes, whose loading runs only
#: skcath's code on numbers, strings and arrays.
TRUSTED_TYPES = tuple(default_trusted())

_HEADER = "skcath.json"
_PAYLOAD = {"joblib": "estimator.joblib", "skops": "estimator.skops"}
_FILE_FORMAT = 1
_RECORDED = ("scikit-learn", "torch", "skorch", "numpy", "joblib", "skops")
_PATH = [str, os.PathLike]


def _release(version: str) -> tuple[int, int]:
    """(major, minor) of a PEP 440 version string (a missing minor counts as 0)."""
    match = re.match(r"\s*v?(\d+)(?:\.(\d+))?", str(version))
    if match is None:
        raise ValueError(f"cannot parse the skcath version {version!r}")
    return int(match[1]), int(match[2] or 0)


@validate_params({"saved": [str], "running": [str, None]}, prefer_skip_nested_validation=True)
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
    running = current_version() if running is None else running
    a, b = _release(saved), _release(running)
    if a[0] != b[0]:
        return False
    return a[0] != 0 or a[1] == b[1]


def _versions() -> dict:
    out = {"skcath": current_version(), "python": platform.python_version()}
    for name in _RECORDED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def _check_suffix(path) -> None:
    """Warn unless ``path`` ends in :data:`SUFFIX`: other tools cannot read the file."""
    if Path(path).suffix.lower() != SUFFIX:
        warnings.warn(
            FileSuffixWarning(
                f"{os.fspath(path)!r} does not end in {SUFFIX!r}: skcath.persist.save writes a "
                "zip archive of a version header and the estimator, which only "
                "skcath.persist.load reads (joblib.load, pickle.load and skops.io.load cannot). "
                f"Name the file {Path(path).stem + SUFFIX!r}."
            ),
            stacklevel=4,  # the caller of save, past validate_params' wrapper
        )


def _skops_payload(estimator) -> bytes:
    """The estimator in the skops format, its residual learners as plain state."""
    import skops.io as sio

    try:
        return sio.dumps(to_plain(estimator))
    except (TypeError, RuntimeError) as exc:
        raise ValueError(
            f"format='skops' cannot serialize this {type(estimator).__name__}: it holds "
            f"objects skops does not know, such as pandas DataFrames ({exc}). Remove them, or "
            "use format='joblib' for a file you will only load yourself (loading it needs "
            "allow_pickle=True)."
        ) from exc


@validate_params(
    {
        "estimator": "no_validation",  # any object joblib can pickle
        "path": _PATH,
        # format and compress are checked in the body, with messages that list the choices
        "format": "no_validation",
        "compress": "no_validation",
    },
    prefer_skip_nested_validation=True,
)
def save(estimator, path, *, format="skops", compress=3) -> None:
    """Save a (fitted) estimator with the versions of skcath and its dependencies.

    Parameters
    ----------
    estimator : object
        Any estimator or pipeline; skcath estimators need not be fitted.
    path : str or os.PathLike
        File to write (overwritten if it exists), named ``*.skcath``
        (:data:`SUFFIX`); another suffix warns with
        :class:`~skcath.exceptions.FileSuffixWarning`, because no other tool
        reads the file.
    format : {"skops", "joblib"}, default="skops"
        Serializer of the estimator. ``"skops"`` stores no pickle:
        :func:`load` builds only skcath's classes (:data:`TRUSTED_TYPES`),
        skops' defaults and the types you name (see
        :func:`get_untrusted_types`). It stores every estimator skcath makes:
        the backbones, :class:`~skcath.residuals.NoResidual`, the residual
        learners :class:`~skcath.residuals.GRUResidual` and
        :class:`~skcath.residuals.MLPResidual` (their network, criterion and
        optimizer state as arrays, rebuilt on loading), pipelines and
        :class:`~skcath.ensemble.SeedEnsembleRegressor` of them,
        :class:`~skcath.online.OnlineEstimator` (started or not, with its
        stream's state), :class:`~skcath.online.ShaftChangeDetector` and
        :class:`~skcath.online.MotorRecalibration`. ``"joblib"`` stores any
        object, as a pickle: loading it runs arbitrary code from the file,
        so :func:`load` refuses it unless ``allow_pickle=True`` (see
        ``docs/persistence.rst``).
    compress : int, default=3
        zlib level (0-9) of the archive members.

    Raises
    ------
    ValueError
        ``format="skops"`` and the estimator holds objects skops cannot store
        (such as a pandas DataFrame).

    Warns
    -----
    FileSuffixWarning
        ``path`` does not end in ``.skcath``.

    See Also
    --------
    load : Read the file back, checking the versions.
    """
    if format not in FORMATS:
        raise ValueError(f"format: expected one of {list(FORMATS)}, got {format!r}")
    if not (isinstance(compress, int) and 0 <= compress <= 9):
        raise ValueError(f"compress: expected an int in [0, 9], got {compress!r}")
    _check_suffix(path)
    if format == "joblib":
        buffer = io.BytesIO()
        joblib.dump(estimator, buffer)
        payload = buffer.getvalue()
    else:
        payload = _skops_payload(estimator)
    header = {
        "file_format": _FILE_FORMAT,
        "format": format,
        "estimator": f"{type(estimator).__module__}.{type(estimator).__qualname__}",
        "versions": _versions(),
    }
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=compress) as zf:
        zf.writestr(_HEADER, json.dumps(header, indent=2))
        zf.writestr(_PAYLOAD[format], payload)


def _pickled(path, name, saved) -> PickledFileError:
    """The error of a joblib-format file loaded without ``allow_pickle``."""
    return PickledFileError(
        f"{os.fspath(path)!r} holds a {name} pickled by joblib (format='joblib', skcath "
        f"{saved}), and unpickling runs any code the file contains, so it is not loaded by "
        "default. If you trust where the file comes from, load it with "
        "skcath.persist.load(path, allow_pickle=True), then save it again in the pickle-free "
        "format: skcath.persist.save(estimator, path) (format='skops', the default)."
    )


def _damaged(path, problem) -> ValueError:
    """The error of a file that :func:`save` did not write, or that was damaged since."""
    return ValueError(
        f"{os.fspath(path)!r} cannot be loaded: {problem}. The file is damaged or was not "
        "written by skcath.persist.save; save the estimator again, or get an intact copy."
    )


#: Errors of reading a member of a damaged zip archive.
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError)


def _read_member(zf, name, path) -> bytes:
    try:
        return zf.read(name)
    except KeyError as exc:
        raise _damaged(path, f"it has no {name}") from exc
    except _ZIP_ERRORS as exc:
        raise _damaged(path, f"its member {name} cannot be read ({exc})") from exc


def _check_header(header, path) -> dict:
    """``header`` if it has every key of a header written by :func:`save`, with its type."""
    if not isinstance(header, dict):
        raise _damaged(path, f"its {_HEADER} holds a {type(header).__name__}, not a JSON object")
    missing = [key for key in ("file_format", "format", "estimator", "versions")
               if key not in header]
    if missing:
        raise _damaged(path, f"its {_HEADER} has no {missing}")
    if header["file_format"] != _FILE_FORMAT or header["format"] not in FORMATS:
        raise ValueError(
            f"{os.fspath(path)!r}: unknown file layout {header['file_format']!r} / format "
            f"{header['format']!r}; it was written by a newer skcath? (layout "
            f"{_FILE_FORMAT} with a format in {list(FORMATS)} expected)"
        )
    versions = header["versions"]
    if not isinstance(header["estimator"], str):
        raise _damaged(path, f"'estimator' of its {_HEADER} is {header['estimator']!r}, "
                             "not a class name")
    if not isinstance(versions, dict) or not isinstance(versions.get("skcath"), str):
        raise _damaged(path, f"'versions' of its {_HEADER} is {versions!r}, not an object "
                             "with the skcath version as a string")
    try:
        _release(versions["skcath"])
    except ValueError as exc:
        raise _damaged(path, str(exc)) from exc
    return header


def _open(path):
    """The open archive at ``path`` and its checked header."""
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise ValueError(
            f"{os.fspath(path)!r} is not a file written by skcath.persist.save: it is not a "
            "zip archive"
        ) from exc
    try:
        if _HEADER not in zf.namelist():
            raise ValueError(
                f"{os.fspath(path)!r} has no {_HEADER}: it was not written by skcath.persist.save"
            )
        raw = _read_member(zf, _HEADER, path)
        try:
            header = json.loads(raw)
        except ValueError as exc:  # not JSON, or not UTF-8
            raise _damaged(path, f"its {_HEADER} is not valid JSON ({exc})") from exc
        return zf, _check_header(header, path)
    except BaseException:
        zf.close()
        raise


@validate_params({"path": _PATH}, prefer_skip_nested_validation=True)
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

    Raises
    ------
    ValueError
        The file is not written by :func:`save`, or its header is damaged.
    """
    zf, header = _open(path)
    zf.close()
    return header


@validate_params({"path": _PATH}, prefer_skip_nested_validation=True)
def get_untrusted_types(path) -> list[str]:
    """Types in a skops-format file that :func:`load` does not trust by default.

    Neither skops' defaults nor skcath's own classes (:data:`TRUSTED_TYPES`).
    Pass the ones you trust to ``load(path, trusted=...)``; a file written
    by :func:`save` from skcath's estimators lists none.

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
        payload = _read_member(zf, _PAYLOAD["skops"], path)
    try:
        untrusted = sio.get_untrusted_types(data=payload)
    except _SKOPS_ERRORS as exc:
        raise _damaged(path, f"its {_PAYLOAD['skops']} cannot be read by skops ({exc})") from exc
    return [name for name in untrusted if name not in TRUSTED_TYPES]


#: Errors of skops reading bytes that are not a skops file.
_SKOPS_ERRORS = (zipfile.BadZipFile, KeyError, ValueError)


def _deserialize(fmt, payload, path, trusted):
    """The estimator in ``payload``; its residual learners built again from their state."""
    if fmt == "joblib":
        try:
            return joblib.load(io.BytesIO(payload))
        except (EOFError, pickle.UnpicklingError) as exc:
            raise _damaged(path, f"its {_PAYLOAD[fmt]} cannot be unpickled ({exc})") from exc
    import skops.io as sio

    trusted = [*TRUSTED_TYPES, *(trusted or ())]
    try:
        schema = read_schema(payload)
    except _SKOPS_ERRORS as exc:
        raise _damaged(path, f"its {_PAYLOAD[fmt]} cannot be read by skops ({exc})") from exc
    check_schema(schema, trusted, path)
    try:
        plain = sio.loads(payload, trusted=trusted)
    except _SKOPS_ERRORS as exc:
        raise _damaged(path, f"its {_PAYLOAD[fmt]} cannot be read by skops ({exc})") from exc
    try:
        return from_plain(plain)
    except ValueError as exc:
        raise ValueError(f"{os.fspath(path)!r}: {exc}") from exc


@validate_params(
    {
        "path": _PATH,
        "trusted": [list, tuple, None],
        "allow_pickle": ["boolean"],
        "allow_version_mismatch": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def load(path, *, trusted=None, allow_pickle=False, allow_version_mismatch=False):
    """Load an estimator saved by :func:`save`, after checking the skcath version.

    A skops-format file (the default of :func:`save`) is built from plain
    data, with only trusted types: skops' defaults, skcath's own classes
    (:data:`TRUSTED_TYPES`) and ``trusted``. A joblib-format file is a
    pickle, which runs any code it holds when it is loaded: it is refused
    unless ``allow_pickle=True``.

    Parameters
    ----------
    path : str or os.PathLike
        File written by :func:`save`.
    trusted : list of str, default=None
        skops format only: types to trust beyond skops' defaults and
        :data:`TRUSTED_TYPES`, as listed by :func:`get_untrusted_types`;
        loading fails if the file holds any other untrusted type. Must be
        None for a joblib file.
    allow_pickle : bool, default=False
        Load a joblib-format file (a pickle, such as the files earlier skcath
        versions wrote by default). Unpickling runs any code the file holds:
        pass True only for a file from a source you trust, and save the
        estimator again with :func:`save` (pickle-free by default).
    allow_version_mismatch : bool, default=False
        Load a file written by an incompatible skcath version anyway (with an
        :class:`~skcath.exceptions.InconsistentVersionWarning`) instead of raising.

    Returns
    -------
    estimator : object

    Raises
    ------
    ValueError
        The file is not a zip archive written by :func:`save`, or it is
        damaged: its header is missing, is not JSON or lacks a key, or a
        member cannot be read. The message names the file and the problem.
        Or a skops-format file holds a skorch net stored as an object (whose
        building would unpickle bytes), which :func:`save` never writes.
    PickledFileError
        The file is in the joblib format and ``allow_pickle`` is False.
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
        running = current_version()
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
        if fmt == "joblib" and not allow_pickle:
            raise _pickled(path, name, saved)
        payload = _read_member(zf, _PAYLOAD[fmt], path)
    with warnings.catch_warnings():
        # one warning from here instead of one per unpickled skcath estimator
        warnings.simplefilter("ignore", InconsistentVersionWarning)
        estimator = _deserialize(fmt, payload, path, trusted)
    if saved != running:
        warnings.warn(
            InconsistentVersionWarning(
                estimator_name=name, original_version=saved, current_version=running
            ),
            stacklevel=2,
        )
    return estimator
