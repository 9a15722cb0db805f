"""facestats.acquire."""
