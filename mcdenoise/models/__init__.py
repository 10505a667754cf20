"""mcdenoise.models (see README)."""
