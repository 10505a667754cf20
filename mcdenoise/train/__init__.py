"""mcdenoise.train (see README)."""
