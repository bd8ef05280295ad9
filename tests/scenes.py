"""Small analytic scenes shared by the tests."""

import numpy as np


def sphere_over_plane(subdivisions=4, radius=1.0, height=2.0, plane_half=6.0):
    """An icosphere of ``radius`` centred at (0, height, 0) over a quad y = 0."""
    import trimesh

    from shadowlab.scene import Scene

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    sphere = Scene(np.asarray(s.vertices) + [0, height, 0], s.faces,
                   np.zeros(len(s.faces)), ("sphere",), "sphere")
    h = plane_half
    quad = Scene(np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], float),
                 np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2), ("ground",), "ground")
    return Scene.concatenate([sphere, quad], name="sphere_over_plane")
