"""facestats.analysis."""
