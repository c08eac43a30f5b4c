"""The one exception type the package raises for problems a user can act on.

Raised deep down, converted to a one-line message and an exit code only in ``cli.py``.
"""

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_BAD_INPUT = 2
EXIT_CALIBRATION_FAILED = 3
EXIT_PARTIAL_BATCH = 4
EXIT_INTERRUPTED = 130  # stopped by SIGINT (Ctrl-C): 128 + 2; what was done is kept
EXIT_TERMINATED = 143  # stopped by SIGTERM (e.g. a job's time limit): 128 + 15


class StereoGeoError(Exception):
    """A problem with the user's input or environment, with the exit code it maps to."""

    def __init__(self, message: str, exit_code: int = EXIT_BAD_INPUT):
        super().__init__(message)
        self.exit_code = exit_code


class CalibrationFailed(StereoGeoError):
    """The pipeline ran but its result cannot be trusted (e.g. a blank image)."""

    def __init__(self, message: str):
        super().__init__(message, EXIT_CALIBRATION_FAILED)
