"""Fleet-scale sweeps and Monte Carlo on Dask (``orange-plan sweep``)."""
