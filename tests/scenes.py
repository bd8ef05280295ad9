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


def half_plane_over_plane(height=2.0, half=30.0):
    """A half-plane occluder {y = height, x < 0} (a quad x in [-half, 0], z in [-half,
    half]) over the ground quad y = 0 (x, z in [-half, half])."""
    from shadowlab.scene import Scene

    h, y = half, height
    ground = Scene(np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], float),
                   np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2), ("ground",), "ground")
    blocker = Scene(np.array([[-h, y, -h], [0, y, -h], [0, y, h], [-h, y, h]], float),
                    np.array([[0, 2, 1], [0, 3, 2]]), np.zeros(2), ("blocker",), "blocker")
    return Scene.concatenate([ground, blocker], name="half_plane_over_plane")


def half_plane_visibility(points, light_pos, light_radius, height):
    """Closed-form visibility [n] of a sphere light (centre ``light_pos``, radius
    ``light_radius``, above ``height``) from ground points [n, 3] (y = 0) under the
    half-plane {y = height, x < 0}: the fraction of the light's silhouette disk (the
    quantity soft_reference samples) not covered.

    A direction u = w + s (x e1 + y e2) over the unit disk (w towards the centre at
    distance D, s = R / sqrt(D^2 - R^2)) hits the occluder's plane at x-coordinate
    p_x + height u_x / u_y, so it is blocked where p_x u_y + height u_x < 0: a half-plane
    a0 + a1 x + a2 y < 0 of the disk; its share is the circular segment at signed
    distance d = a0 / |(a1, a2)| from the centre, (acos d - d sqrt(1 - d^2)) / pi.
    """
    p = np.asarray(points, float)
    to_c = np.asarray(light_pos, float) - p
    dist = np.linalg.norm(to_c, axis=1)
    w = to_c / dist[:, None]
    s = light_radius / np.sqrt(dist ** 2 - light_radius ** 2)
    helper = np.where(np.abs(w[:, :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(helper, w)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(w, e1)

    def f(v):
        return p[:, 0] * v[:, 1] + height * v[:, 0]

    a0, a1, a2 = f(w), s * f(e1), s * f(e2)
    d = np.clip(a0 / np.maximum(np.hypot(a1, a2), 1e-300), -1.0, 1.0)
    blocked = (np.arccos(d) - d * np.sqrt(1.0 - d * d)) / np.pi
    return 1.0 - blocked
