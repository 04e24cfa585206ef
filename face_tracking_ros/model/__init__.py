"""The face model: mesh topology (19/34 named nodes) and the deformable model of eq. 3."""
