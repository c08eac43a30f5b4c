"""One rig from many of its pairs: what both ``batch-calibrate --same-rig`` and ``calibrate-sequence`` stand
on. No I/O and no processes here, only the maths of combining pairs. Each module imports only those above it:

- :mod:`~stereogeo_cli.rig.evidence`: :class:`PairEvidence`, what one calibrated pair tells of its rig.
- :mod:`~stereogeo_cli.rig.combine`: the robust combinations (focal lengths in log f, directions,
  rotations) and what a rig's focal length read from its images reports as its sigma.
- :mod:`~stereogeo_cli.rig.start`: the rig's R and T from its pairs, and the baseline rule.
"""
