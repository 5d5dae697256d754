"""Command-line apps and reports of rgbd-envmap."""
