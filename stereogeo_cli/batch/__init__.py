"""``batch-calibrate``: every stereo pair of a folder, one network session per process.

- :mod:`~stereogeo_cli.batch.discovery`: which files form the pairs, and the shards of a job array.
- :mod:`~stereogeo_cli.batch.run`: the pairs in worker processes, progress, per-pair results, summaries.
- :mod:`~stereogeo_cli.batch.same_rig`: ``--same-rig``, one calibration of a rig from all its pairs.
- :mod:`~stereogeo_cli.batch.interrupt`: stopping cleanly on SIGINT / SIGTERM (for any long command).
- :mod:`~stereogeo_cli.batch.resume`: what a pair's folder records, so that ``--resume`` can keep it.
"""

from stereogeo_cli.batch.discovery import (
    IMAGE_EXTENSIONS,
    PairEntry,
    discover_pairs,
    parse_shard,
    select_shard,
)
from stereogeo_cli.batch.run import (
    RIG_FOLDER,
    BatchSummary,
    PairJob,
    PairOutcome,
    RigEvidence,
    _evidence,
    calibrate_pair,
    run_batch,
)
from stereogeo_cli.batch.same_rig import (
    FOCAL_COMMON_SHARE,
    FocalEstimate,
    _with_exif_prior,
    calibrate_rig,
    chordal_mean,
    combine_focals,
    pool_matches,
)

__all__ = [
    "FOCAL_COMMON_SHARE", "IMAGE_EXTENSIONS", "RIG_FOLDER", "BatchSummary", "FocalEstimate", "PairEntry",
    "PairJob", "PairOutcome", "RigEvidence", "_evidence", "_with_exif_prior", "calibrate_pair",
    "calibrate_rig", "chordal_mean", "combine_focals", "discover_pairs", "parse_shard", "pool_matches",
    "run_batch", "select_shard",
]  # fmt: skip
