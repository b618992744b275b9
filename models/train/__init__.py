"""Training code (torch); never imported by the runtime."""
