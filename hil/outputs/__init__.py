"""A run's folder: summary, CAN log, rerun recording, plots."""
