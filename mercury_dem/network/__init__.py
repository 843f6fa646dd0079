"""Control networks: columnar model, building from matches, merging, validation, storage, ISIS files."""
