"""Batch runs beyond one process: recording archives and large evaluations on Dask (issue 16).

``executor``: where tasks run (this process, a local Dask cluster, an existing one); ``detect``: detection over
many recordings split per frame range; ``evaluate``: the exposure sweep split per pose range; ``synthetic``:
small simulated archives for tests and ``livetrack bench-batch``. See docs/batch.md.
"""
