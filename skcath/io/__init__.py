"""Read recordings exported by other tools into the long recording format.

- :func:`read_recording`: one CSV or Parquet file in any column naming;
- :func:`read_ndi_csv`: an NDI Aurora / Track CSV export (tracker stream);
- :func:`align_streams` / :func:`read_streams`: a motor log and a tracker log
  with their own clocks and rates, aligned in time;
- :func:`read_rosbag`: a ROS 1 or ROS 2 bag (needs the optional package
  ``rosbags``);
- :func:`read_recordings`: many runs at once, ids from the file names or a
  manifest.

CSV files are read as UTF-8 text with the delimiter and decimal mark found
in the file; a cut last line is dropped with a
:class:`~skcath.exceptions.TruncatedFileWarning`, and a file that cannot be
read is a ValueError naming the file. See ``docs/data_format.rst`` for the
long format, the column names and how files are read.
"""

from ._align import AlignmentReport, align_streams, read_streams
from ._many import read_recordings
from ._convert import VALID_STRINGS
from ._ndi import read_ndi_csv
from ._recording import read_recording
from ._ros import read_rosbag

__all__ = [
    "VALID_STRINGS",
    "AlignmentReport",
    "align_streams",
    "read_ndi_csv",
    "read_recording",
    "read_recordings",
    "read_rosbag",
    "read_streams",
]
