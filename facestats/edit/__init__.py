"""facestats.edit."""
