"""The reports: scene reports (`validate report`), their sweeps and plots, and every report's provenance."""
