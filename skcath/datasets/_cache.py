"""The benchmark cache on disk: a Bunch of frames, arrays and JSON values in one ``.npz`` file.

Nothing in a cache file is pickled. :func:`write_bunch` stores every numeric
column and array as a ``.npy`` member, text as fixed-width unicode arrays,
categorical columns as their codes and categories, and everything else as
JSON in the member ``__meta__``; :func:`read_bunch` opens the file with
``numpy.load(..., allow_pickle=False)``. A file planted in the cache folder
can therefore hold wrong data at worst, never code that runs on loading.
"""

import json

import numpy as np
import pandas as pd
from sklearn.utils import Bunch

__all__ = ["CACHE_FORMAT", "SUFFIX", "as_json_value", "read_bunch", "read_key", "write_bunch"]

#: Layout of the cache files; bumped when :func:`write_bunch` or the fields
#: of a benchmark change (2: the drift columns of ``runs``).
CACHE_FORMAT = 2

#: Suffix of the cache files.
SUFFIX = ".npz"

_META = "__meta__"


def as_json_value(value):
    """``value`` as JSON gives it back: plain floats, lists, dicts with string keys.

    Raises
    ------
    TypeError
        ``value`` holds something JSON cannot store.
    """
    return json.loads(json.dumps(value, allow_nan=True))


def _is_text(series):
    """Whether a column holds text (and missing values) only."""
    if isinstance(series.dtype, pd.StringDtype):
        return True
    if series.dtype != object:
        return False
    return all(isinstance(v, str) for v in series[series.notna()])


def _column_arrays(series, prefix):
    """Members and description of one column (or of the categories of one)."""
    dtype = series.dtype
    if isinstance(dtype, pd.CategoricalDtype):
        arrays, categories = _column_arrays(pd.Series(dtype.categories), f"{prefix}/categories")
        arrays[prefix] = series.cat.codes.to_numpy()
        return arrays, {"kind": "category", "ordered": bool(dtype.ordered), "categories": categories}
    if _is_text(series):
        missing = series.isna().to_numpy()
        text = np.array(["" if m else v for v, m in zip(series.tolist(), missing)], dtype=str)
        return {prefix: text, f"{prefix}/missing": missing}, {"kind": "text", "dtype": str(dtype)}
    values = series.to_numpy()
    if values.dtype == object or values.dtype != dtype:
        raise TypeError(
            f"the benchmark cache stores numeric, text and categorical columns; "
            f"column {series.name!r} has dtype {dtype}"
        )
    return {prefix: values}, {"kind": "values"}


def _column(npz, prefix, spec):
    """The column described by ``spec`` from the members under ``prefix``."""
    if spec["kind"] == "category":
        categories = _column(npz, f"{prefix}/categories", spec["categories"])
        return pd.Series(
            pd.Categorical.from_codes(npz[prefix], pd.Index(categories), ordered=spec["ordered"])
        )
    if spec["kind"] == "text":
        values = npz[prefix].astype(object)
        values[npz[f"{prefix}/missing"]] = None
        return pd.Series(values, dtype=object).astype(spec["dtype"])
    return pd.Series(npz[prefix])


def _frame_arrays(frame, name):
    """Members and description of a DataFrame with a RangeIndex."""
    index = frame.index
    if not isinstance(index, pd.RangeIndex):
        raise TypeError(f"the benchmark cache stores frames with a RangeIndex; {name} has none")
    arrays, columns = {}, []
    for k, column in enumerate(frame.columns):
        members, spec = _column_arrays(frame[column], f"{name}/{k}")
        arrays.update(members)
        columns.append({"name": column, **spec})
    spec = {"kind": "frame", "columns": columns,
            "index": [index.start, index.stop, index.step, index.name]}
    return arrays, spec


def _frame(npz, name, spec):
    start, stop, step, index_name = spec["index"]
    columns = {c["name"]: _column(npz, f"{name}/{k}", c) for k, c in enumerate(spec["columns"])}
    frame = pd.DataFrame(columns)
    frame.index = pd.RangeIndex(start, stop, step, name=index_name)
    return frame


def write_bunch(file, bunch, key):
    """Write ``bunch`` (frames, arrays and JSON values) to ``file`` without pickling.

    Parameters
    ----------
    file : file object
        Opened for writing in binary mode.
    bunch : sklearn.utils.Bunch
        pandas DataFrames (with a RangeIndex; numeric, text or categorical
        columns), numeric numpy arrays, and values that JSON stores exactly.
    key : dict
        What identifies the bunch; :func:`read_key` gives it back.

    Raises
    ------
    TypeError
        A field cannot be stored exactly.
    """
    arrays, fields = {}, {}
    for name, value in bunch.items():
        if isinstance(value, pd.DataFrame):
            members, fields[name] = _frame_arrays(value, name)
            arrays.update(members)
        elif isinstance(value, np.ndarray) and value.dtype != object:
            arrays[name] = value
            fields[name] = {"kind": "array"}
        elif as_json_value(value) == value:
            fields[name] = {"kind": "json", "value": value}
        else:
            raise TypeError(f"the benchmark cache cannot store the field {name!r} exactly")
    meta = {"cache_format": CACHE_FORMAT, "key": key, "fields": fields}
    arrays[_META] = np.array(json.dumps(meta))
    np.savez(file, **arrays)


def _meta(npz):
    meta = json.loads(str(npz[_META]))
    if meta.get("cache_format") != CACHE_FORMAT:
        raise ValueError(f"cache layout {meta.get('cache_format')!r}, expected {CACHE_FORMAT}")
    return meta


def read_key(path):
    """The key a cache file was written with, reading nothing else.

    Raises
    ------
    Exception
        Whatever ``numpy.load`` or ``json`` raise on a file that is not a
        cache file (never code from the file: pickled members are refused).
    """
    with np.load(path, allow_pickle=False) as npz:
        return _meta(npz)["key"]


def read_bunch(path):
    """The Bunch stored at ``path`` by :func:`write_bunch`; pickled members are refused."""
    with np.load(path, allow_pickle=False) as npz:
        meta = _meta(npz)
        bunch = Bunch()
        for name, spec in meta["fields"].items():
            if spec["kind"] == "frame":
                bunch[name] = _frame(npz, name, spec)
            elif spec["kind"] == "array":
                bunch[name] = npz[name]
            else:
                bunch[name] = spec["value"]
    return bunch
