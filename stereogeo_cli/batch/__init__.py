"""``batch-calibrate``: every stereo pair of a folder, one network session per process.

Each module imports only those above it:

- :mod:`~stereogeo_cli.batch.records`: the job of a pass, each pair's outcome and what it tells of its rig.
- :mod:`~stereogeo_cli.batch.resume`: what a pair's folder records, so that ``--resume`` can keep it.
- :mod:`~stereogeo_cli.batch.passes`: one pass over the pairs, in this process or in worker processes.
- :mod:`~stereogeo_cli.batch.same_rig`: ``--same-rig``, one calibration of a rig from all its pairs.
- :mod:`~stereogeo_cli.batch.run`: the whole batch, its per-pair results and its summaries.

Which files form the pairs is :mod:`stereogeo_cli.io.pairs`; stopping on a signal and progress are
:mod:`stereogeo_cli.jobs`; the maths of combining pairs into one rig is :mod:`stereogeo_cli.rig`.
"""

from stereogeo_cli.batch.records import RIG_FOLDER, BatchOptions, PairJob, PairOutcome
from stereogeo_cli.batch.run import BatchSummary, run_batch
from stereogeo_cli.batch.same_rig import calibrate_rig

__all__ = [
    "RIG_FOLDER", "BatchOptions", "BatchSummary", "PairJob", "PairOutcome", "calibrate_rig", "run_batch",
]  # fmt: skip
