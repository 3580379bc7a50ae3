"""HTML pages for the validation reports: `write_viewer` writes one report's page (an HDR image viewer on
float data, Plotly plots, tables, verdicts, provenance); `write_index` lists every report under a folder."""
from .index import write_index
from .page import BlockTest, Plot, Series, write_viewer

__all__ = ["BlockTest", "Plot", "Series", "write_index", "write_viewer"]
