"""rgbd-envmap: real-time RGB-D environment capture and relighting (Monroy, Hudon, Smolic 2018).

The library never imports the simulator (``sim``) or the apps; packets may come from either a live
simulation or a recorded log.
"""

__version__ = "0.1.0"
