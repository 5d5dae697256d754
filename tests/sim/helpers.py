"""Scenes built in code for simulator tests, with closed-form answers."""

from __future__ import annotations


def box_room(half: float = 2.0, radiance=(0.5, 0.4, 0.3), extra: list | None = None) -> dict:
    """A cube room [−half, half]³ whose six walls are quads of constant radiance."""
    h = half
    walls = [
        ("floor", [-h, -h, -h], [2 * h, 0, 0], [0, 2 * h, 0]),
        ("ceiling", [-h, -h, h], [2 * h, 0, 0], [0, 2 * h, 0]),
        ("north", [-h, h, -h], [2 * h, 0, 0], [0, 0, 2 * h]),
        ("south", [-h, -h, -h], [2 * h, 0, 0], [0, 0, 2 * h]),
        ("east", [h, -h, -h], [0, 2 * h, 0], [0, 0, 2 * h]),
        ("west", [-h, -h, -h], [0, 2 * h, 0], [0, 0, 2 * h]),
    ]
    objects = [{"name": n, "shape": "quad", "corner": c, "u": u, "v": v, "radiance": list(radiance)} for n, c, u, v in walls]
    return {"name": "box_room", "virtual_object_position": [0, 0, 0], "objects": objects + (extra or [])}
