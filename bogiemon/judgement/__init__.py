"""The verdict of each window: sensor health, gating, load state, the decision and its diagnosis.

Pure (no I/O beyond reading its shipped model files, no threads, no clocks): the same call onboard
(daemon/monitor.py) and in the back office (fleet/judge.py). judgement/verdict.py is the one entry.
"""
