"""metro.report."""
