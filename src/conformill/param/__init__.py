"""param stage."""
