"""metro.io."""
