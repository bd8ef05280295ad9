"""Scenes (triangle soups, loaded or procedural), cameras, lights and animations;
edge adjacency (:mod:`.adjacency`) and light-space cameras (:mod:`.light_camera`)."""

from .mesh import (ObjectReport, Scene, SceneError, SceneReport, SUPPORTED_FORMATS,
                   load_scene, mesh_report)
from .view import (Animation, Camera, DirectionalLight, Light, PointLight, SphereLight, View,
                   hard_light)
from .procedural import GENERATORS, default_view, generators, make
from .adjacency import Adjacency, AdjacencyReport, build_adjacency
from .light_camera import LightCamera, LightFace, box_corners, fit_light_camera

__all__ = [
    "Adjacency", "AdjacencyReport", "LightCamera", "LightFace", "box_corners",
    "build_adjacency", "fit_light_camera",
    "Animation", "Camera", "DirectionalLight", "GENERATORS", "Light", "ObjectReport",
    "PointLight", "SUPPORTED_FORMATS", "Scene", "SceneError", "SceneReport", "SphereLight",
    "View", "default_view", "generators", "hard_light", "load_scene", "make", "mesh_report",
]
