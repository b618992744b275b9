"""Files and wire formats: MCAP sessions and their codecs, BVH, result files, export, Foxglove."""
