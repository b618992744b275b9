"""Studies and figure scripts (not installed): run from a checkout with ``python -m research.NAME``."""
