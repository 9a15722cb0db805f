"""Reliability and safety of facestats under hostile input and faults (issue #12)."""
