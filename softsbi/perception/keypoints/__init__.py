"""Keypoint extractors (image -> K keypoints): supervised heatmaps and the unsupervised Transporter."""
