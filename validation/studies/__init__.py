"""The studies of the report's proposed improvements (`validate improvements`): pixel filters, adaptive sampling, denoising."""
