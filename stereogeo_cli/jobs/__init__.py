"""What every long command (``batch-calibrate``, ``calibrate-sequence``) shares: stopping cleanly on SIGINT
and SIGTERM (:mod:`~stereogeo_cli.jobs.interrupt`) and showing its progress on stderr
(:mod:`~stereogeo_cli.jobs.progress`)."""
