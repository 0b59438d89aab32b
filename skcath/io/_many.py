"""Read many recordings at once into one long table.

:func:`read_recordings` reads every file of a folder (or of a glob pattern, or
listed in a manifest CSV) with :func:`skcath.io.read_recording`, takes the
catheter, setting and run ids from the file names or the manifest, and
concatenates the runs.
"""

import glob
import re
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import validate_params
from tqdm.auto import tqdm

from .._format import CATHETER, ID_COLUMNS, RUN, SETTING, channel_index
from .._sweep_end import N_SWEEP_ATTR
from .._validation import check_recordings
from ._errors import naming_the_file
from ._options import OPTION_NAMES, check_option_names
from ._quat import check_quat_orders, declared_order, neutral_poses
from ._recording import CSV_SUFFIXES, PARQUET_SUFFIXES, file_kind, read_with_poses

__all__ = ["read_recordings"]

#: Manifest columns that are not read options.
_MANIFEST_PATH = "path"

#: Options a manifest may hold as whole numbers, read back as floats when the
#: column has an empty cell.
_INTEGER_OPTIONS = ("n_sweep", CATHETER, SETTING, RUN)


def _is_table(path):
    """True for a file whose suffix :func:`read_recording` supports (:func:`~skcath.io._recording.file_kind`)."""
    if not path.is_file():
        return False
    try:
        file_kind(path)
    except ValueError:
        return False
    return True


def _files_of(source):
    """Files named by a folder or a glob pattern, sorted by path.

    Parameters
    ----------
    source : str or path-like
        Folder (its CSV / Parquet files, not recursive) or glob pattern
        (``**`` matches sub-folders).

    Returns
    -------
    paths : list of pathlib.Path

    Raises
    ------
    ValueError
        If nothing matches.
    """
    text = str(source)
    if Path(text).is_dir():
        paths = sorted(p for p in Path(text).iterdir() if _is_table(p))
        where = f"the folder {text!r} has no CSV or Parquet file"
    else:
        paths = sorted(Path(p) for p in glob.glob(text, recursive=True) if _is_table(Path(p)))
        where = f"no CSV or Parquet file matches {text!r}"
    if not paths:
        raise ValueError(
            f"{where} (suffixes {', '.join((*CSV_SUFFIXES, *PARQUET_SUFFIXES))})."
        )
    return paths


def _check_pattern(pattern):
    """Compile the file-name pattern; its named groups must be id names."""
    if pattern is None:
        return None
    try:
        regex = re.compile(pattern)
    except (TypeError, re.error) as exc:
        raise ValueError(
            f"pattern must be a regular expression with named groups; got {pattern!r} "
            f"({exc})."
        ) from None
    unknown = set(regex.groupindex) - set(ID_COLUMNS)
    if not regex.groupindex or unknown:
        raise ValueError(
            f"pattern must have named groups among {list(ID_COLUMNS)}, e.g. "
            r"'(?P<run>(?P<catheter>[^_]+)_(?P<setting>[^_]+)_r\d+)'; got "
            f"{pattern!r}" + (f" with the unknown group(s) {sorted(unknown)}." if unknown else ".")
        )
    return regex


def _read_manifest(manifest):
    """Read the manifest into a list of ``(path, per-file options)``.

    Parameters
    ----------
    manifest : str, path-like or pandas.DataFrame
        CSV file (paths relative to its folder) or table.

    Returns
    -------
    jobs : list of (pathlib.Path, dict)

    Raises
    ------
    ValueError
        If the manifest cannot be read as CSV, has no ``path`` column or
        lists a file that does not exist.
    """
    if isinstance(manifest, pd.DataFrame):
        table, root, name = manifest, Path("."), "manifest"
    else:
        manifest = Path(manifest)
        if not manifest.is_file():
            raise ValueError(f"manifest: no such file {str(manifest)!r}.")
        with naming_the_file(manifest, "a CSV manifest"):
            table = pd.read_csv(manifest)
        root, name = manifest.parent, manifest.name
    if _MANIFEST_PATH not in table.columns:
        raise ValueError(
            f"{name}: the manifest needs a {_MANIFEST_PATH!r} column; columns: "
            f"{list(table.columns)}."
        )
    unknown = [c for c in table.columns if c != _MANIFEST_PATH and c not in OPTION_NAMES]
    if unknown:
        raise ValueError(
            f"{name}: the manifest has the unknown column(s) {unknown}; besides "
            f"{_MANIFEST_PATH!r} its columns must be reading options {list(OPTION_NAMES)}."
        )
    jobs = []
    for i, row in enumerate(table.to_dict("records")):
        raw = row.pop(_MANIFEST_PATH)
        if not isinstance(raw, str) or not raw.strip():
            raise ValueError(f"{name}: row {i} has no path.")
        path = Path(raw)
        path = path if path.is_absolute() else root / path
        if not path.is_file():
            raise ValueError(
                f"{name}: row {i} lists {raw!r}, which does not exist ({str(path)!r})."
            )
        options = {}
        for key, value in row.items():
            if isinstance(value, float) and np.isnan(value):
                continue  # an empty cell: option not given for this file
            if isinstance(value, (np.integer, np.floating)):
                value = value.item()
            if key in _INTEGER_OPTIONS and isinstance(value, float) and value.is_integer():
                value = int(value)  # a column with an empty cell is read as floats
            if key == "n_sweep" and isinstance(value, str) and value.strip().isdigit():
                value = int(value)  # a column mixing numbers and "auto" is read as text
            options[key] = value
        jobs.append((path, options))
    if not jobs:
        raise ValueError(f"{name}: the manifest lists no file.")
    return jobs


def _channels(X):
    """The motor and torque columns of a recording read, as a list."""
    return [c for c in X.columns if channel_index(c) is not None]


def _read_files(jobs, read_kwargs, progress, quat_check):
    """Read every file of ``jobs``; check the ids, the channels and the quaternion order.

    Parameters
    ----------
    jobs : list of (pathlib.Path, dict)
        Files and their own options (ids from the pattern or the manifest).
    read_kwargs : dict
        Options shared by every file.
    progress : bool
        Show a progress bar.
    quat_check : bool
        Check the quaternion order against the data
        (:func:`~skcath.io._quat.check_quat_orders`).

    Returns
    -------
    frames : list of pandas.DataFrame
    targets : list of ndarray of shape (n_rows, 3)
    """
    frames, targets, owner, neutral = [], [], {}, []
    for path, options in tqdm(jobs, disable=not progress, desc="reading", unit="file"):
        clash = set(options) & set(read_kwargs)
        if clash:
            raise ValueError(
                f"{path.name}: {sorted(clash)} given both for this file (pattern or "
                "manifest) and as a keyword argument for all files; give one or the other."
            )
        X, y, poses = read_with_poses(path, **options, **read_kwargs)
        if quat_check:
            found = neutral_poses(X, poses, declared_order({**options, **read_kwargs}))
            neutral += [] if found is None else [found]
        for run in pd.unique(X[RUN].astype(str)):
            if run in owner:
                raise ValueError(
                    f"the run id {run!r} is in both {owner[run]!r} and {path.name!r}; a run id "
                    "must be unique across all files (across catheters and settings too). Give "
                    "each file its own run id, e.g. a pattern whose run group spans the "
                    "catheter and setting, r'(?P<run>(?P<catheter>[^_]+)_(?P<setting>[^_]+)_r\\d+)', "
                    "or a manifest 'run' column."
                )
            owner[run] = path.name
        if frames and list(X.columns) != list(frames[0].columns):
            first = next(iter(owner.values()))
            raise ValueError(
                f"{path.name} has the channels {_channels(X)} but {first} has "
                f"{_channels(frames[0])}; the runs of one data set have the same motors "
                "and either all have torques or none (pass constants=... or torques=False "
                "to read them alike)."
            )
        frames.append(X)
        targets.append(y)
    if quat_check:
        check_quat_orders(neutral)
    return frames, targets


@validate_params(
    {
        "source": "no_validation",
        "pattern": "no_validation",
        "manifest": "no_validation",
        "progress": ["boolean"],
        "quat_check": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def read_recordings(
    source=None,
    *,
    pattern=None,
    manifest=None,
    progress=True,
    quat_check=True,
    **read_kwargs,
):
    """Read many recording files into one long table.

    Parameters
    ----------
    source : str or path-like, default=None
        A folder (all its CSV / Parquet files, not recursive) or a glob
        pattern such as ``"data/**/*.csv"``. Files are read in sorted path
        order. Give ``source`` or ``manifest``.
    pattern : str, default=None
        Regular expression matched against the whole file name without its
        suffix (:func:`re.fullmatch`), whose named groups ``catheter``,
        ``setting`` and/or ``run`` give the ids of the file, e.g.
        ``r"(?P<run>(?P<catheter>[^_]+)_(?P<setting>[^_]+)_run\\d+)"`` for
        ``A_slow_run3.csv`` (run ``A_slow_run3``). Ids are strings. A run id
        must be unique across all files, so a run group that is only a
        repeat number (``_run(?P<run>\\d+)``) works only when no number
        repeats. Without ``pattern``, ids come from the files themselves or
        ``read_kwargs`` (``run`` defaults to the file name).
    manifest : str, path-like or pandas.DataFrame, default=None
        Instead of ``source``: a table (CSV file, or a DataFrame) with a
        ``path`` column (relative to the manifest file's folder, or to the
        working directory for a DataFrame) and optional columns ``catheter``,
        ``setting``, ``run`` and other per-file options of
        :func:`read_recording` (``n_sweep``, ``rate_hz``, ``phase``, ...).
        An empty cell leaves that option unset for that file; an ``n_sweep``
        column may mix numbers and ``"auto"``.
    progress : bool, default=True
        Show a tqdm progress bar over the files.
    quat_check : bool, default=True
        Check the quaternion order against the data when the target is
        computed from raw sensor poses: read in the right order, a catheter's
        tip at the neutral pose of its sweep points the same way in the base
        frame in every run; read in the wrong one, it scatters as soon as the
        base sensor turns between runs
        (:func:`skcath.frames.fit_quat_order`). A ValueError names the order
        that fits. Where the data cannot tell (one run per catheter, or a
        base sensor that keeps its orientation), the files pass. False skips
        the check, for a rig where the neutral tip of a catheter does not
        keep its direction across runs.
    **read_kwargs
        Options of :func:`skcath.io.read_recording` shared by every file
        (``columns``, ``constants``, ``n_sweep``, ...).

    Returns
    -------
    X : pandas.DataFrame
        All runs one after the other, index ``range(n_rows)``.
    y : ndarray of shape (n_rows, 3)
        Tip in the base frame (mm).

    Raises
    ------
    TypeError
        On a keyword argument that is not a reading option (the message
        lists them).
    sklearn.utils._param_validation.InvalidParameterError
        If ``progress`` is not a bool.
    ValueError
        If both or neither of ``source`` and ``manifest`` are given, both
        ``pattern`` and ``manifest``; no file matches; a file name does not
        match ``pattern`` (the message names it); an id is given by the
        pattern or manifest and also in ``read_kwargs``; a manifest file does
        not exist; two files hold the same (catheter, setting, run); or a
        file cannot be read (the message names the file); or, with
        ``quat_check``, the base quaternions fit the other order than they
        were read in.

    Examples
    --------
    ::

        X, y = read_recordings(
            "recordings/",
            pattern=r"(?P<run>(?P<catheter>[^_]+)_(?P<setting>[^_]+)_r\\d+)",
            n_sweep=200,
        )
    """
    if (source is None) == (manifest is None):
        raise ValueError("Give either source (a folder or glob) or manifest, not both.")
    if pattern is not None and manifest is not None:
        raise ValueError("Give either pattern or manifest for the ids, not both.")
    regex = _check_pattern(pattern)
    check_option_names(read_kwargs, "read_recordings")

    if manifest is not None:
        jobs = _read_manifest(manifest)
    else:
        jobs = []
        for path in _files_of(source):
            options = {}
            if regex is not None:
                stem = file_kind(path)[1]
                match = regex.fullmatch(stem)
                if match is None:
                    raise ValueError(
                        f"the file name {path.name!r} does not match pattern "
                        f"{pattern!r} (matched against {stem!r})."
                    )
                options = {k: v for k, v in match.groupdict().items() if v is not None}
            jobs.append((path, options))

    frames, targets = _read_files(jobs, read_kwargs, progress, quat_check)
    # the joined table must be valid recordings as a whole, as every reader's output is;
    # each file's sweep was checked as its options asked (phase="motion": none)
    given = {run: n for X in frames for run, n in X.attrs.get(N_SWEEP_ATTR, {}).items()}
    X, y = check_recordings(
        pd.concat(frames, ignore_index=True), np.concatenate(targets, axis=0), require_sweep=False
    )
    X.attrs.pop(N_SWEEP_ATTR, None)
    if given:  # the n_sweep given for each run, whatever the other files' options
        X.attrs[N_SWEEP_ATTR] = given
    return X, y
