"""Contact laws: Hertz spring, 2D Winkler bedding and 3D Kalker (elastic half-space)."""
