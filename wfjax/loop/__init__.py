"""The time loop: its setup, state, contact solve, observers and the scan (``run``)."""
