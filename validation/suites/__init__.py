"""The suites: many comparisons run as one (`validate calibrate`, `coverage`, `mitsuba-tests`, `faults`, `stability`, `fuzz`, `snapshot`)."""
