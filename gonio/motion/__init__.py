"""Motion: time of pose-to-pose moves, ordering of poses, campaign duration and its lower bound."""
