"""Which controller a compiled step runs (the ``mode`` of :func:`~skcath.control._jit.control_step`)."""

__all__ = ["MODE_FEEDFORWARD", "MODE_INTERNAL_MODEL", "MODE_RESOLVED_RATE"]

#: The controller of a compiled step: the feedforward, the feedback as an internal-model
#: loop (``feedforward=True``), the feedback by resolved rate (``feedforward=False``).
MODE_FEEDFORWARD, MODE_INTERNAL_MODEL, MODE_RESOLVED_RATE = 0, 1, 2
