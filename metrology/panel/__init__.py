"""metro.panel."""
