"""Learning the face model from 3-D meshes: alignment (§3.3), §3.4 and joint learners."""
