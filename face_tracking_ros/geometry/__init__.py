"""Geometry: rotations (Rodrigues), cameras (eq. 1 and 2), Procrustes and RMS distances."""
