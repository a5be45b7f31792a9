"""Scene files (YAML): validation (:mod:`.scene`), files on disk and their bases (:mod:`.files`)."""
