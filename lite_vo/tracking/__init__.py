"""Direct SE(3) tracking against the semi-dense inverse-depth map (numba kernels + Tracker)."""
