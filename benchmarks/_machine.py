"""Description of the machine and of the code a benchmark ran on, shared by the benchmark scripts."""

import datetime
import hashlib
import os
import platform
from pathlib import Path


def machine_lines():
    """Date, Python, CPU count and model, and library versions, one string per line."""
    lines = [
        f"date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}",
        f"python {platform.python_version()} on {platform.platform()}",
        f"logical CPUs: {os.cpu_count()}",
    ]
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), None)
        if model:
            lines.append(f"CPU: {model}")
    except OSError:
        pass
    import numpy
    import pandas
    import scipy

    lines.append(f"numpy {numpy.__version__}, scipy {scipy.__version__}, pandas {pandas.__version__}")
    return lines


def source_digest(package):
    """Fingerprint of a package's sources, so that a table can be matched to the code.

    Parameters
    ----------
    package : module
        A package, e.g. ``skcath.datasets``.

    Returns
    -------
    digest : str
        The first 12 hex digits of the sha1 of the names and contents of the
        ``*.py`` files in the package's folder, in name order.
    """
    digest = hashlib.sha1()
    for path in sorted(Path(package.__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:12]
