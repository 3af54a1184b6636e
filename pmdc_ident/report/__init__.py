"""Report plots (matplotlib, Agg backend)."""
