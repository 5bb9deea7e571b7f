"""From a photo to heights: the quaternion filter, the segmentation and the inflation."""
