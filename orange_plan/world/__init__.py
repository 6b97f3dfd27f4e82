"""The world a robot moves in: map loading and validation, rasters, terrain queries."""

from orange_plan.world.geomap import Map, Surface, load_map
from orange_plan.world.terrain import World

__all__ = ["Map", "Surface", "World", "load_map"]
