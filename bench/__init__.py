"""In-situ calibration bench for subsea manipulators (TA-40), after the PUC-Rio thesis in ``shared/seed``."""

__version__ = "0.1.0"
