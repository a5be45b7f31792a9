"""Scene files (YAML): validation (:mod:`.scene`), files on disk and bases (:mod:`.files`)."""
