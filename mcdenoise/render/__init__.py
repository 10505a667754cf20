"""mcdenoise.render: scene specs -> Mitsuba 3 renders and data sets (docs/rendering.md)."""
