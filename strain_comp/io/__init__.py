"""Reading and writing recordings: MCAP bags, per-sensor recordings, tensile-tester CSVs."""
