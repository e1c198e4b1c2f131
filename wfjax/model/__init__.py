"""Physics: wheel, track (modal model), supports, vehicle, flat geometry."""
