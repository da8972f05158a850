"""Pure geometry: projection and (un)distortion, epipolar geometry, triangulation."""
