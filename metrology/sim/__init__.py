"""metro.sim."""
