"""facestats.io."""
