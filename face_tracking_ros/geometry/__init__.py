"""Geometry: rotations (Rodrigues), pinhole and stereo cameras (eq. 1 and 2), Procrustes."""
