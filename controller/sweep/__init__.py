"""Controller tuning sweeps: candidates over controller settings, plant variants and reference, run as one batch."""
