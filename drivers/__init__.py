"""livecap drivers package."""
