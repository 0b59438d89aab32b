"""Description of the machine a benchmark ran on, shared by the benchmark scripts."""

import datetime
import os
import platform


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
