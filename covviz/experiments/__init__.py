"""Run -> results on disk -> report: ``covviz bench`` (jobs, Dask cluster), result files, reports, Optuna tuning."""
