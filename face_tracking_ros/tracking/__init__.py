"""Face trackers: the monocular model-based tracker of eq. 6 and what they share."""
