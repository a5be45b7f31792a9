"""Scene files (YAML): loading, validation and defaults (:mod:`.scene`)."""
