"""``ncgate sweep``: every variant of a program library, as independent ``ncgate sim`` runs,
on the cores of this machine or on a Dask cluster, into one table (docs/sweep.md).

Only this package imports Dask (``cluster.py``) and pyarrow (``table.py``), each when it is
used: the ``ncgate[dask]`` and ``ncgate[parquet]`` extras.
"""
