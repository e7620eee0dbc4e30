"""Scenario sweeps (``swarm sweep``): a mission flown over many seeds and settings, locally or on Ray, with
statistics. plan.py says what runs, runs.py flies one, sweep.py flies them all (resuming), cluster.py on Ray,
stats.py and summary.py sum them up (docs/sweeps.md)."""
