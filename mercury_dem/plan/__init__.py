"""The plan of a run that is not data: the merge tree (:mod:`mercury_dem.plan.tree`). Pure, no I/O."""
