"""Errors of the file parsers, turned into errors that name the file.

Every reader of :mod:`skcath.io` parses its files inside
:func:`naming_the_file`. Whatever a parser raises about the content of a file
(a compressed stream cut short, bytes that are not text, a damaged Parquet
footer, bag index or bag metadata, a CSV line with too many fields, ...)
becomes a :class:`ValueError` that starts with the file name, says what was
found and chains the original exception. Errors that already name the file
pass unchanged: the readers' own messages, :class:`OSError` about the path
(no such file, no permission) and :class:`ImportError` for a missing optional
package.
"""

import lzma
import zipfile
from contextlib import contextmanager
from pathlib import PurePath

__all__ = ["naming_the_file"]

#: What an exception type says about the file, in the words of a user.
_FINDINGS = (
    (EOFError, "it ends early: it was cut short while being written or copied"),
    (
        UnicodeDecodeError,
        "it holds bytes that are not UTF-8 text (a binary or damaged file, or text in "
        "another encoding)",
    ),
    (
        (zipfile.BadZipFile, lzma.LZMAError, OSError),
        "its compressed data are damaged, or it is not compressed as its suffix says",
    ),
)


def _passes(exc, name):
    """Whether ``exc`` already names the file and is left as it is."""
    if isinstance(exc, (ImportError, MemoryError)):
        return True
    if isinstance(exc, OSError) and exc.filename is not None:
        return True  # no such file, a folder, no permission: the path is in the message
    return type(exc) is ValueError and str(exc).startswith(f"{name}:")


def _finding(exc):
    """A sentence on what the exception says about the file, or None."""
    for types, text in _FINDINGS:
        if isinstance(exc, types):
            return text
    return None


@contextmanager
def naming_the_file(path, kind):
    """Turn an error raised while parsing ``path`` into a ValueError naming the file.

    Parameters
    ----------
    path : path-like
        File (or bag folder) being read.
    kind : str
        What the file is read as (``"CSV"``, ``"Parquet"``, ``"a ROS bag"``),
        for the message.

    Raises
    ------
    ValueError
        ``"<file name>: cannot be read as <kind>: <what was found>
        (<exception type>: <original message>)"``, chained to the original
        exception, for every exception that does not already name the file.
    """
    name = PurePath(path).name
    try:
        yield
    except Exception as exc:
        if _passes(exc, name):
            raise
        finding = _finding(exc)
        found = f"{finding} " if finding else ""
        raise ValueError(
            f"{name}: cannot be read as {kind}: {found}({type(exc).__name__}: {exc})"
        ) from exc
