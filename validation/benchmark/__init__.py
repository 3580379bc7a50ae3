"""The benchmark (`validate bench`): the tracer and Mitsuba timed side by side, and the scenes it generates."""
