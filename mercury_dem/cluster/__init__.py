"""Batch systems: the SLURM/PBS launcher (``mercury-dem cluster``, ``run --cluster``) and its job shapes."""
