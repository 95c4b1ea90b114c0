"""starnav.cli."""
