"""Light through the media mesh: pinhole-camera rays, shading, images (``bentray render``)."""
