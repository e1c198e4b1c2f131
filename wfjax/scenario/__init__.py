"""What runs: descriptions of a run and their checks (no compiled code)."""
