"""The synthetic face world: true faces, motion, rendering and bags with ground truth."""
