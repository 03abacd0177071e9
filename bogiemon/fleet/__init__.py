"""The back office: a fleet's recordings re-analysed on Dask, judged as each gateway does, shown on one page."""
