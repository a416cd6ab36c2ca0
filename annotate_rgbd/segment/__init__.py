"""The per-frame stage: rasterise the shapes, drop planes by the EVOPS rules, find each plane
(RANSAC), keep its inliers at the sensor's noise, grow its edges."""
