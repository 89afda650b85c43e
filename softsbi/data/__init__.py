"""On-disk formats read and written by softsbi: recordings, DiffCloud folders, keypoint sets."""
