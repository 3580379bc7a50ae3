"""The validation harness: Mitsuba 3 ground truth and statistical comparisons against it."""
