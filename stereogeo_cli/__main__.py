"""The ``stereogeo`` command (and ``python -m stereogeo_cli``)."""

import os
import signal


def _terminated(signum, frame) -> None:
    # SIGTERM before a command has its own handlers (while Python loads the libraries): nothing has been
    # done yet, so the process ends at once, with one line and the exit code a shell gives SIGTERM
    os.write(2, b"error: interrupted by SIGTERM\n")
    os._exit(128 + signal.SIGTERM)


def run() -> None:
    signal.signal(signal.SIGTERM, _terminated)
    # Before NumPy loads: its OpenBLAS would keep a thread per core for the small products of the refiner,
    # the fusion and the matcher, and those threads spin, taking CPU from the network and from the other
    # batch workers (about 60 ms of CPU per 640x480 pair; docs/batch.md, "Speed"). Spawned batch workers
    # inherit the setting. An explicit OPENBLAS_NUM_THREADS wins.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from stereogeo_cli.cli import main

    main()


if __name__ == "__main__":
    run()
