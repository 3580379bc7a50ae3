"""The verdict: `validate check` and what it stands on (the statistics, the renderers, scene planning, the protocol, Mitsuba's references)."""
