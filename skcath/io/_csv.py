"""The text of a CSV file, its delimiter and decimal mark, a cut last line dropped.

:func:`read_csv_text` is how every CSV reader of :mod:`skcath.io` opens its
file. It decompresses the file by its suffix, decodes it as UTF-8 and finds
the dialect from the text:

- the **delimiter** is the one of ``,``, ``;`` and tab that splits the header
  line into the most fields (``,`` on a tie);
- the **decimal mark** is ``,`` when a file delimited by ``;`` or tab writes
  its numbers with decimal commas (``12,5``), otherwise ``.``;
- a **cut last line**, one that does not end with a line break or holds
  fewer fields than the header and the line before it (a recording
  interrupted while the file was written), is dropped with a
  :class:`~skcath.exceptions.TruncatedFileWarning`.

What cannot be read this way is an error naming the file: bytes that are not
UTF-8 text, a damaged compressed stream, an empty file, a line with more
fields than the header (in a ``,`` file, decimal commas do that), numbers
written with both decimal marks.
"""

import bz2
import csv
import gzip
import lzma
import re
import warnings
import zipfile
from dataclasses import dataclass

from ..exceptions import TruncatedFileWarning
from ._errors import naming_the_file

__all__ = ["DELIMITERS", "CsvText", "read_csv_text"]

#: Delimiters told apart, in order of preference on a tie.
DELIMITERS = (",", ";", "\t")
#: Non-blank lines after the header that are sampled for the dialect checks.
_SAMPLE_LINES = 200
#: Characters of the file searched for the sampled lines.
_HEAD_CHARS = 1 << 20
_OPENERS = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}
_COMMA_NUMBER = re.compile(r"[+-]?(\d+,\d*|,\d+)([eE][+-]?\d+)?")
_POINT_NUMBER = re.compile(r"[+-]?(\d+\.\d*|\.\d+)([eE][+-]?\d+)?")
_LINE_BREAKS = "\r\n"


@dataclass(frozen=True)
class CsvText:
    """A CSV file read as text, with its dialect.

    Attributes
    ----------
    text : str
        The decoded text, without a cut last line.
    sep : str
        Delimiter, one of :data:`DELIMITERS`.
    decimal : str
        Decimal mark of the numbers, ``"."`` or ``","``.
    """

    text: str
    sep: str
    decimal: str


def _file_bytes(path):
    """The bytes of the file, decompressed by the suffix (``.gz``, ``.bz2``, ``.xz``, ``.zip``).

    Raises
    ------
    ValueError
        If a zip archive does not hold exactly one file.
    """
    suffix = path.suffix.lower()
    if suffix == ".zip":
        with zipfile.ZipFile(path) as archive:
            members = [m for m in archive.namelist() if not m.endswith("/")]
            if len(members) != 1:
                raise ValueError(
                    f"{path.name}: the zip archive holds {len(members)} files "
                    f"{members[:5]}; it must hold exactly one CSV file."
                )
            return archive.read(members[0])
    opener = _OPENERS.get(suffix)
    if opener is None:
        return path.read_bytes()
    with opener(path, "rb") as handle:
        return handle.read()


def _fields(line, sep):
    """The cells of one CSV line (quotes respected)."""
    return next(csv.reader([line], delimiter=sep), [])


def _first_lines(text):
    """``(line number, line)`` of the first non-blank lines: the header and a sample."""
    head = text[:_HEAD_CHARS]
    lines = head.splitlines()
    if len(head) < len(text) and len(lines) > 1:
        lines = lines[:-1]  # the prefix may cut its last line
    numbered = [(k, line) for k, line in enumerate(lines, start=1) if line.strip()]
    return numbered[: _SAMPLE_LINES + 1]


def _delimiter(header):
    """The delimiter that splits the header into the most fields, ``,`` on a tie."""
    return max(DELIMITERS, key=lambda sep: len(_fields(header, sep)))


def _check_widths(path, rows, width, sep):
    """Raise if a sampled line has more fields than the header.

    Parameters
    ----------
    path : pathlib.Path
        File, for messages.
    rows : list of (int, list of str)
        Line number and cells of the sampled lines after the header.
    width : int
        Fields of the header.
    sep : str
        Delimiter.

    Raises
    ------
    ValueError
        Naming the line, its fields and the header's; for a file delimited
        by ``,`` it says that decimal commas split numbers in two.
    """
    for number, cells in rows:
        if len(cells) > width:
            hint = (
                " If the file writes decimal commas (12,5), every such number is split in "
                "two: export it with ';' as the delimiter, or with decimal points."
                if sep == ","
                else ""
            )
            raise ValueError(
                f"{path.name}: line {number} has {len(cells)} fields but the header has "
                f"{width} (delimiter {sep!r}); every line needs one field per column."
                f"{hint}"
            )


def _decimal_mark(path, rows):
    """``","`` when the sampled cells write decimal commas, else ``"."``.

    Raises
    ------
    ValueError
        If numbers are written with both decimal marks.
    """
    cells = [cell.strip() for _, row in rows for cell in row]
    commas = [cell for cell in cells if _COMMA_NUMBER.fullmatch(cell)]
    points = [cell for cell in cells if _POINT_NUMBER.fullmatch(cell)]
    if commas and points:
        raise ValueError(
            f"{path.name}: the file writes numbers with decimal commas (e.g. {commas[0]!r}) "
            f"and with decimal points (e.g. {points[0]!r}); write every number with one "
            "decimal mark."
        )
    return "," if commas else "."


def _last_line(text, end):
    """Start and end of the last non-blank line of ``text[:end]``."""
    while end > 0 and text[end - 1] in " " + _LINE_BREAKS:
        end -= 1
    start = max(text.rfind("\n", 0, end), text.rfind("\r", 0, end)) + 1
    return start, end


def _without_cut_last_line(path, text, header_start, header_width, sep):
    """``text`` without its last line if that line looks cut (with a warning).

    The last line looks cut when it does not end with a line break, or when
    it has fewer fields than both the header and the line before it.

    Parameters
    ----------
    path : pathlib.Path
        File, for the warning.
    text : str
        Decoded text.
    header_start : int
        Offset of the header line in ``text``.
    header_width : int
        Fields of the header.
    sep : str
        Delimiter.

    Returns
    -------
    text : str
    """
    start, end = _last_line(text, len(text))
    if start <= header_start:
        return text  # a header and no line after it
    last = text[start:end]
    width = len(_fields(last, sep))
    before = text[slice(*_last_line(text, start))]
    reference = min(header_width, len(_fields(before, sep)))
    if not any(c in _LINE_BREAKS for c in text[end:]):
        reason = "does not end with a line break"
    elif width < reference:
        reason = f"has {width} fields where the header and the line before it have more"
    else:
        return text
    shown = last if len(last) <= 60 else last[:57] + "..."
    warnings.warn(
        f"{path.name}: the last line {reason} ({shown!r}), as when a recording is "
        "interrupted while the file is written; its values cannot be trusted, so the "
        "line was dropped. Complete the line (and end it with a line break) to read it.",
        TruncatedFileWarning,
        stacklevel=2,
    )
    return text[:start]


def read_csv_text(path, *, wider_rows=False):
    """Read a CSV file as text and find its delimiter and decimal mark.

    Parameters
    ----------
    path : pathlib.Path
        A ``.csv`` file, or one compressed as its suffix says (``.gz``,
        ``.bz2``, ``.xz``, ``.zip`` holding one file).
    wider_rows : bool, default=False
        Accept lines with more fields than the header (tracker exports that
        append marker data); otherwise such a line is an error.

    Returns
    -------
    csv_text : CsvText
        The text without a cut last line, the delimiter and the decimal mark.

    Raises
    ------
    ValueError
        Naming the file: it cannot be decompressed or decoded as UTF-8,
        holds NUL bytes, is empty, has a line with more fields than the
        header (unless ``wider_rows``), or writes numbers with both decimal
        marks.

    Warns
    -----
    skcath.exceptions.TruncatedFileWarning
        When the last line looks cut; it is dropped.
    """
    with naming_the_file(path, "CSV"):
        text = _file_bytes(path).decode("utf-8-sig")
    if "\x00" in text:
        raise ValueError(
            f"{path.name}: cannot be read as CSV: it holds NUL bytes, as binary files do; "
            "a CSV file is text."
        )
    lines = _first_lines(text)
    if not lines:
        raise ValueError(f"{path.name}: the file is empty (no header, no rows).")
    header = lines[0][1]
    sep = _delimiter(header)
    width = len(_fields(header, sep))
    rows = [(number, _fields(line, sep)) for number, line in lines[1:]]
    if not wider_rows:
        _check_widths(path, rows, width, sep)
    decimal = _decimal_mark(path, rows) if sep != "," else "."
    header_start = re.search(r"[^ \r\n]", text).start()
    text = _without_cut_last_line(path, text, header_start, width, sep)
    return CsvText(text, sep, decimal)
