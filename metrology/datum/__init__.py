"""metro.datum."""
