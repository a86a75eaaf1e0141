"""Where everything sits, derived from a scene (one place for the geometry conventions).

Axes as in the paper: x along the DEA (clamp face at x = 0, free end at x = -length),
y vertical (up, gravity along -y, ground at y = 0), z across the width (centred).
The DEA's underside is clamped ``dea.clamp_gap_m`` above the obstacle's top face (coin
or stop), or at y = 0 when the scene has neither; gravity lets it down onto the obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Optional

from deapull.scene import Scene


@dataclass(frozen=True)
class Layout:
    length_m: float
    width_m: float
    y_bottom_m: float           # DEA underside
    active_y_m: tuple           # (y_min, y_max) of the active stack
    passive_y_m: tuple          # (y_min, y_max) of the passive layer
    obstacle_center_x_m: Optional[float]
    obstacle_top_y_m: Optional[float]
    obstacle_radius_m: Optional[float]

    @property
    def thickness_m(self) -> float:
        return max(self.active_y_m[1], self.passive_y_m[1]) - self.y_bottom_m


@lru_cache(maxsize=16)
def layout(scene: Scene) -> Layout:
    """Where everything of ``scene`` sits. Computed once per scene: the mesher's steps and
    the problem ask for it by the (frozen, hashable) scene and get the same object."""
    d = scene.dea
    obstacle = scene.coin or scene.stop
    top = (scene.coin.height_m if scene.coin else scene.stop.height_m) if obstacle else 0.0
    base = top + d.clamp_gap_m
    lower, upper = (d.passive_thickness_m, d.active_thickness_m)
    if d.active_side == "bottom":
        lower, upper = upper, lower
    y_mid = base + lower
    lower_range, upper_range = (base, y_mid), (y_mid, y_mid + upper)
    active, passive = (upper_range, lower_range) if d.active_side == "top" else (lower_range, upper_range)
    return Layout(
        length_m=d.length_m, width_m=d.width_m, y_bottom_m=base, active_y_m=active, passive_y_m=passive,
        obstacle_center_x_m=(-d.length_m + obstacle.center_from_tip_m) if obstacle else None,
        obstacle_top_y_m=top if obstacle else None,
        obstacle_radius_m=obstacle.radius_m if obstacle else None,
    )
