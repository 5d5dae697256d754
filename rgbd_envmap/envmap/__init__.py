"""The RGB-D environment map (paper 003 §6): its state, the update rules, colour pairs, translation.

- :mod:`~rgbd_envmap.envmap.map`: :class:`EnvironmentMap` (planar float32 radiance, distance from
  the origin, valid flags) and its change log;
- :mod:`~rgbd_envmap.envmap.rules`: the update rules, one scalar function each;
- :mod:`~rgbd_envmap.envmap.map_update`: :func:`update`, a frame's samples into the map;
- :mod:`~rgbd_envmap.envmap.pairs`: colour pairs and frame samples;
- :mod:`~rgbd_envmap.envmap.translation`: :func:`translate`, depth-aware or Gardner's.

Every public name is available from this package (``from rgbd_envmap import envmap;
envmap.update(...)``).
"""

from rgbd_envmap.envmap.map import MAX_MAP_PIXELS, ChangeLog, EnvironmentMap, MapChanges, check_map
from rgbd_envmap.envmap.pairs import collect_pairs, frame_pair_sums, frame_pairs, frame_points, frame_samples
from rgbd_envmap.envmap.rules import is_backface, rule_closer, rule_empty, rule_freed, rule_removal, rule_trusted
from rgbd_envmap.envmap.translation import TRANSLATE_METHODS, translate
from rgbd_envmap.envmap.map_update import SeenDepth, UpdateConfig, UpdateStats, clip_flags, update, view_distances

__all__ = [
    "EnvironmentMap",
    "check_map",
    "MAX_MAP_PIXELS",
    "MapChanges",
    "ChangeLog",
    "SeenDepth",
    "UpdateConfig",
    "UpdateStats",
    "update",
    "view_distances",
    "clip_flags",
    "collect_pairs",
    "frame_points",
    "frame_pairs",
    "frame_pair_sums",
    "frame_samples",
    "translate",
    "TRANSLATE_METHODS",
    "rule_empty",
    "rule_closer",
    "rule_trusted",
    "rule_removal",
    "rule_freed",
    "is_backface",
]
