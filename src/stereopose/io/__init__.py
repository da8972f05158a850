"""Input and output: video/stream readers, result writers, demo data."""
