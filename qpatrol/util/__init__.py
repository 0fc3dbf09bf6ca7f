"""Small helpers every layer may use: atomic writes, CSV reading, progress bars, provenance,
flat indexing of arrays."""
