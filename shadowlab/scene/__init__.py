"""Scenes (triangle soups, loaded or procedural), cameras, lights and animations."""

from .mesh import (ObjectReport, Scene, SceneError, SceneReport, SUPPORTED_FORMATS,
                   load_scene, mesh_report)
from .view import (Animation, Camera, DirectionalLight, Light, PointLight, SphereLight, View,
                   hard_light)
from .procedural import GENERATORS, default_view, generators, make
from .adjacency import Adjacency, AdjacencyReport, build_adjacency

__all__ = [
    "Adjacency", "AdjacencyReport", "build_adjacency",
    "Animation", "Camera", "DirectionalLight", "GENERATORS", "Light", "ObjectReport",
    "PointLight", "SUPPORTED_FORMATS", "Scene", "SceneError", "SceneReport", "SphereLight",
    "View", "default_view", "generators", "hard_light", "load_scene", "make", "mesh_report",
]
