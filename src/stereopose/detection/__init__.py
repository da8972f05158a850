"""Person detection: detector backends and readers/writers of 2D keypoint files."""
