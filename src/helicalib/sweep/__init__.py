"""Sweeps: a grid of whole simulated campaigns (seeds × scenarios × planners × start times on one
field), run on Dask distributed, gathered into one table with a mean and a 95 % t-interval per cell.

``spec`` reads and checks the sweep file and lays out the runs with their seeds; ``task`` is one
run as a worker executes it; ``results`` builds the table and the per-cell statistics;
``engine`` submits the runs to a Dask client and collects them. ``docs/sweep.md`` describes the
file, the outputs and how to run on a cluster.
"""
