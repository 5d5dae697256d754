"""Command-line apps and reports of rgbd-envmap (importing this package changes nothing; the entry
points set the process's thread settings: :mod:`apps.process`)."""
