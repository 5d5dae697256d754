"""rgbd-envmap: real-time RGB-D environment capture and relighting (Monroy, Hudon, Smolic 2018).

The library never imports the simulator (``sim``) or the apps; packets may come from either a live
simulation or a recorded log.
"""

__version__ = "0.1.0"

#: names loaded on first use (importing the package itself stays cheap and does nothing else).
_LAZY = {"replay": "rgbd_envmap.api", "RunResult": "rgbd_envmap.api"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rgbd_envmap' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
