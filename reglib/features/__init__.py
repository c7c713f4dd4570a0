"""Feature extraction and descriptor matching: SIFT for photographs, shape context for contours."""
