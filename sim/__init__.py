"""livecap sim package."""
