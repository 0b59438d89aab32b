"""The skcath version, in a leaf module read by the package and by persistence."""

__version__ = "0.1.0.dev0"


def current_version():
    """The running skcath version (``skcath.__version__``), read at call time.

    Returns
    -------
    version : str
        A PEP 440 version string.
    """
    return __version__
