"""Reports (tables, figures) and the CI gate over a run's tidy results table."""
