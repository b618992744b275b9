"""The runner (every-frame and latest-frame modes), the pipeline stages and stats.json."""
