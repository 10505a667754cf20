"""mcdenoise.render (see README)."""
