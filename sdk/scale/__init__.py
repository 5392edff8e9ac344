"""Scale out on Dask: ``weldcell batch`` (an offline command over many inputs) and ``weldcell study``
(Monte-Carlo trials of a simulated job).

* :mod:`~weldcell.sdk.scale.cluster`: where tasks run (embedded LocalCluster, an existing cluster, or
  this process) and the check that every worker has weldcell and the same plugins;
* :mod:`~weldcell.sdk.scale.tasks`: a task's attempts, time limit and atomic publication;
* :mod:`~weldcell.sdk.scale.batch` and :mod:`~weldcell.sdk.scale.study`: the two commands' core;
* :mod:`~weldcell.sdk.scale.progress` and :mod:`~weldcell.sdk.scale.report`: progress bar, CSV, HTML.

Dask (the ``scale`` extra) is imported only when a cluster is used. See docs/scale-out.md.
"""
