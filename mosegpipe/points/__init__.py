"""Points and their trajectories: KLT tracks, SIFT pairs, the dense flow and its point grid, the trajectory matrix."""
