"""livecap models package."""
