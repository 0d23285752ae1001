"""metro.diagnosis."""
