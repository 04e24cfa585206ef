"""Drawing of meshes on images, shared by the overlay topic and the overlay command."""
