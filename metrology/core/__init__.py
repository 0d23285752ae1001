"""metro.core."""
