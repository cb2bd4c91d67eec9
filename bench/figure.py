"""Character-like test scenes with thin limbs in coarse cages, posed by rotating the cage around joints.

Two scenes, both made here from numbers (no data files):

* :func:`figure`: a figure in T-pose (z up, facing -y, about 1.9 tall): torso, head, two arms ending in two-fingered
  hands, two legs ending in two-toed feet, a thin tail. The mesh is one swept tube per part (smooth, closed, about
  30k vertices in all; the parts overlap at the body, as separate shells). The cage is box-modelled: a subdivided box
  for the torso, every limb extruded from its faces ring by ring, the fingers and toes split from the hand's and
  foot's end faces, so its limbs are one or two quads across (about 200 vertices, quads). The fingertips and toe tips
  poke out of the cage (a few hundred vertices outside, as on real characters).
* :func:`tentacle`: a long tapered tube in a tapered hexagonal cage closed by a point; its tip pokes out of the cage.

A pose is a set of joint rotations (degrees about an axis, in the rest frame, each about its joint's rest position,
applied child after parent). Every cage vertex follows one joint chain; the ring at a joint turns by half the joint's
rotation (a mitred joint, no skinning shrink), the rings between joints rigidly.

Used by bench/creases.py and tests/test_smoothing.py (a smaller tentacle).
"""

import numpy as np
from scipy.spatial.transform import Rotation


class Skeleton:
    """Joints with parents and rest positions; :meth:`transforms` gives each joint's posed rigid motion."""

    def __init__(self):
        self.parent, self.position, self.names = [], [], {}

    def add(self, name, parent, position):
        self.names[name] = len(self.parent)
        self.parent.append(-1 if parent is None else self.names[parent])
        self.position.append(np.asarray(position, dtype=float))
        return name

    def transforms(self, rotations, fraction=1.0, joint=None):
        """(R, t) of every joint: x ↦ R x + t for a point carried by it; ``rotations`` {name: (axis, degrees)}.

        The joint ``joint``, if given, turns by ``fraction`` of its rotation (its parents in full)."""
        result = []
        for index, parent in enumerate(self.parent):
            axis, degrees = rotations.get(self._name(index), ((1.0, 0.0, 0.0), 0.0))
            share = fraction if joint is not None and index == self.names[joint] else 1.0
            local = Rotation.from_rotvec(np.radians(degrees * share) * unit(axis)).as_matrix()
            pivot = self.position[index]
            rotation, shift = local, pivot - local @ pivot
            if parent >= 0:
                parent_rotation, parent_shift = result[parent]
                rotation, shift = parent_rotation @ rotation, parent_rotation @ shift + parent_shift
            result.append((rotation, shift))
        return result

    def _name(self, index):
        return next(name for name, value in self.names.items() if value == index)


class BoxModel:
    """A closed polygon mesh made by box modelling: a subdivided box, faces extruded ring by ring.

    Every vertex records the joint it follows and the share of that joint's rotation it takes (1 inside a bone,
    1/2 on the ring at a joint)."""

    def __init__(self, lo, hi, divisions, joint, z_levels=None):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        axes = [np.linspace(lo[k], hi[k], divisions[k] + 1) for k in range(3)]
        if z_levels is not None:
            axes[2] = np.asarray(z_levels, float)
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        shape = grid.shape[:3]
        on_surface = np.zeros(shape, dtype=bool)
        on_surface[[0, -1]] = on_surface[:, [0, -1]] = on_surface[:, :, [0, -1]] = True
        index = -np.ones(shape, dtype=int)
        index[on_surface] = np.arange(on_surface.sum())
        self.vertices = list(grid[on_surface])
        self.joint = [(joint, 1.0)] * len(self.vertices)
        self.faces = []
        nx, ny, nz = divisions
        for i in range(nx):
            for j in range(ny):
                self.faces.append([index[i, j, 0], index[i, j + 1, 0], index[i + 1, j + 1, 0], index[i + 1, j, 0]])
                self.faces.append([index[i, j, nz], index[i + 1, j, nz], index[i + 1, j + 1, nz], index[i, j + 1, nz]])
        for i in range(nx):
            for k in range(nz):
                self.faces.append([index[i, 0, k], index[i + 1, 0, k], index[i + 1, 0, k + 1], index[i, 0, k + 1]])
                self.faces.append([index[i, ny, k], index[i, ny, k + 1], index[i + 1, ny, k + 1], index[i + 1, ny, k]])
        for j in range(ny):
            for k in range(nz):
                self.faces.append([index[0, j, k], index[0, j, k + 1], index[0, j + 1, k + 1], index[0, j + 1, k]])
                self.faces.append([index[nx, j, k], index[nx, j + 1, k], index[nx, j + 1, k + 1], index[nx, j, k + 1]])

    def find(self, centre, normal):
        """Indices of the faces whose centre is within 1e-6 of a point of the plane through ``centre`` with normal
        ``normal`` and whose own normal points along it, sorted by distance from ``centre``."""
        normal = unit(normal)
        found = []
        for index, face in enumerate(self.faces):
            corners = np.array([self.vertices[v] for v in face])
            own = np.cross(corners[1] - corners[0], corners[2] - corners[0])
            if abs(np.dot(corners.mean(axis=0) - centre, normal)) < 1e-6 and np.dot(unit(own), normal) > 0.99:
                found.append((np.linalg.norm(corners.mean(axis=0) - centre), index))
        return [index for _, index in sorted(found)]

    def extrude(self, faces, move, joint, share=1.0):
        """Extrude the region ``faces`` (indices): its vertices copied through ``move`` ((k, 3) → (k, 3)), side quads
        joining the old boundary to the new; the region's faces now use the copies. Returns the side faces' indices."""
        region = sorted({v for face in faces for v in self.faces[face]})
        copies = {}
        moved = move(np.array([self.vertices[v] for v in region]))
        for v, position in zip(region, moved):
            copies[v] = len(self.vertices)
            self.vertices.append(position)
            self.joint.append((joint, share))
        edges = {(f[k], f[(k + 1) % len(f)]) for face in faces for f in [self.faces[face]] for k in range(len(f))}
        sides = []
        for a, b in sorted(edges):
            if (b, a) not in edges:
                sides.append(len(self.faces))
                self.faces.append([a, b, copies[b], copies[a]])
        for face in faces:
            self.faces[face] = [copies[v] for v in self.faces[face]]
        return sides

    def arrays(self):
        return np.array(self.vertices), [list(map(int, f)) for f in self.faces]


def ring(target, centre, half, axis):
    """A ``move`` for :meth:`BoxModel.extrude`: the region put at ``target`` along ``axis`` (0, 1 or 2) and scaled about
    ``centre`` (its position on the other axes) to the half-sizes ``half`` (the other axes in order)."""
    others = [k for k in range(3) if k != axis]

    def move(points):
        points = points.copy()
        points[:, axis] = target
        for k, size in zip(others, half):
            points[:, k] = centre[k] + size / np.abs(points[:, k] - centre[k]).max() * (points[:, k] - centre[k])
        return points
    return move


def unit(vector):
    vector = np.asarray(vector, dtype=float)
    return vector / np.linalg.norm(vector)


def tube(path, radii, spacing, around):
    """A closed tube swept along a polyline (rounded where it turns), hemispherical ends.

    Parameters
    ----------
    path : (k, 3) float array
    radii : (k,) float array
        Radius at each path point (linear in arc length between them).
    spacing : float
        About the distance between rings.
    around : int
        Vertices per ring.

    Returns
    -------
    vertices : (m, 3) float array
    faces : (F, 3) int array, outward
    """
    path, radii = np.asarray(path, float), np.asarray(radii, float)
    centre, radius = _rounded(path, radii, spacing)
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    # Parallel transport of a normal along the curve.
    normal = np.cross(tangent[0], [0.3, 0.5, 0.8])
    normal /= np.linalg.norm(normal)
    normals = [normal]
    for k in range(1, len(centre)):
        normal = normal - np.dot(normal, tangent[k]) * tangent[k]
        normal /= np.linalg.norm(normal)
        normals.append(normal)
    normals = np.array(normals)
    binormals = np.cross(tangent, normals)
    # Hemispherical caps: rings at the ends' radii times sin, set back by cos along the tangent.
    cap = max(2, int(np.ceil(np.pi / 2 * radius[0] / spacing)))
    start = [(centre[0] - tangent[0] * radius[0] * np.cos(a), radius[0] * np.sin(a), tangent[0], normals[0],
              binormals[0]) for a in np.linspace(0, np.pi / 2, cap + 1)[1:-1]]
    cap = max(2, int(np.ceil(np.pi / 2 * radius[-1] / spacing)))
    end = [(centre[-1] + tangent[-1] * radius[-1] * np.cos(a), radius[-1] * np.sin(a), tangent[-1], normals[-1],
            binormals[-1]) for a in np.linspace(0, np.pi / 2, cap + 1)[1:-1][::-1]]
    rings = start + list(zip(centre, radius, tangent, normals, binormals)) + end
    angle = 2 * np.pi * np.arange(around) / around
    vertices = np.concatenate([c + r * (np.cos(angle)[:, None] * n + np.sin(angle)[:, None] * b)
                               for c, r, _, n, b in rings])
    poles = np.array([centre[0] - tangent[0] * radius[0], centre[-1] + tangent[-1] * radius[-1]])
    count = len(rings)
    bottom, top = count * around, count * around + 1
    k = np.arange(around)
    following = (k + 1) % around
    faces = [np.stack([np.full(around, bottom), following, k], axis=1)]
    for row in range(count - 1):
        a, b = row * around + k, row * around + following
        faces += [np.stack([a, b, b + around], axis=1), np.stack([a, b + around, a + around], axis=1)]
    last = (count - 1) * around
    faces.append(np.stack([np.full(around, top), last + k, last + following], axis=1))
    faces = np.concatenate(faces)
    vertices = np.vstack([vertices, poles])
    # The ring's orientation (normal × binormal = tangent) makes these outward; check on the first side triangle.
    corners = vertices[faces[around]]
    outward = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    if np.dot(outward, corners.mean(axis=0) - centre[0]) < 0:
        faces = faces[:, ::-1]
    return vertices, faces


def _rounded(path, radii, spacing):
    """Points about ``spacing`` apart along ``path`` with its corners rounded (a quadratic Bézier from the middle of
    each segment to the next), and the radius at each."""
    lengths = np.linalg.norm(np.diff(path, axis=0), axis=1)
    along = np.concatenate([[0], np.cumsum(lengths)])
    samples = np.linspace(0, along[-1], max(3, int(np.ceil(along[-1] / spacing)) + 1))
    points = np.stack([np.interp(samples, along, path[:, k]) for k in range(3)], axis=1)
    radius = np.interp(samples, along, radii)
    for corner in range(1, len(path) - 1):
        reach = 0.5 * min(lengths[corner - 1], lengths[corner])
        inside = np.abs(samples - along[corner]) < reach
        t = (samples[inside] - (along[corner] - reach)) / (2 * reach)
        a = path[corner] + (path[corner - 1] - path[corner]) * reach / lengths[corner - 1]
        c = path[corner] + (path[corner + 1] - path[corner]) * reach / lengths[corner]
        points[inside] = ((1 - t) ** 2)[:, None] * a + (2 * t * (1 - t))[:, None] * path[corner] + (t ** 2)[:, None] * c
    return points, radius


def figure(spacing=0.009):
    """The figure scene.

    Returns
    -------
    vertices : (m, 3) float array
    faces : (F, 3) int array
        Triangles, one closed shell per part.
    cage : (n, 3) float array
    cage_faces : list of index lists (quads)
    pose : callable(rotations) -> (n, 3) float array
        The cage posed by {joint name: (axis, degrees)}.
    """
    skeleton = Skeleton()
    skeleton.add("hips", None, (0, 0, 1.1))
    skeleton.add("chest", "hips", (0, 0, 1.25))
    skeleton.add("neck", "chest", (0, 0, 1.53))
    z_levels = (0.95, 1.225, 1.3625, 1.5)
    model = BoxModel((-0.2, -0.11, z_levels[0]), (0.2, 0.11, z_levels[-1]), (4, 1, 3), "hips", z_levels)
    # The torso's upper half follows the chest; its middle ring turns by half.
    for index, position in enumerate(model.vertices):
        if position[2] > 1.3:
            model.joint[index] = ("chest", 1.0)
        elif position[2] > 1.2:
            model.joint[index] = ("chest", 0.5)
    parts = []  # (path, radii, around) of each tube
    parts.append(([(0, 0, 1.06), (0, 0, 1.39)], [0.1, 0.1], 40))
    # Head: the middle two of the top faces, a neck ring, then the head.
    top = model.find((0, 0, 1.5), (0, 0, 1))[:2]
    model.extrude(top, ring(1.56, (0, 0, 1.5), (0.05, 0.05), 2), "neck", 0.5)
    model.extrude(top, ring(1.62, (0, 0, 1.5), (0.13, 0.12), 2), "neck")
    model.extrude(top, ring(1.87, (0, 0, 1.5), (0.13, 0.12), 2), "neck")
    parts.append(([(0, 0, 1.42), (0, 0, 1.62)], [0.04, 0.04], 24))
    parts.append(([(0, 0, 1.73), (0, 0, 1.75)], [0.09, 0.09], 40))
    arm_z = (z_levels[1] + z_levels[3]) / 2  # the arms come out of the two upper levels' side faces
    for side in (-1, 1):
        name = "L" if side < 0 else "R"
        skeleton.add(f"shoulder{name}", "chest", (side * 0.26, 0, arm_z))
        skeleton.add(f"elbow{name}", f"shoulder{name}", (side * 0.55, 0, arm_z))
        skeleton.add(f"wrist{name}", f"elbow{name}", (side * 0.8, 0, arm_z))
        skeleton.add(f"knuckleA{name}", f"wrist{name}", (side * 0.92, 0, arm_z + 0.0375))
        skeleton.add(f"knuckleB{name}", f"wrist{name}", (side * 0.92, 0, arm_z - 0.0375))
        faces = model.find((side * 0.2, 0, arm_z), (side, 0, 0))[:2]
        centre = (side * 0.2, 0.0, arm_z)
        model.extrude(faces, ring(side * 0.28, centre, (0.05, 0.06), 0), f"shoulder{name}", 0.5)
        model.extrude(faces, ring(side * 0.55, centre, (0.045, 0.05), 0), f"elbow{name}", 0.5)
        model.extrude(faces, ring(side * 0.8, centre, (0.035, 0.04), 0), f"wrist{name}", 0.5)
        model.extrude(faces, ring(side * 0.92, centre, (0.0275, 0.075), 0), f"wrist{name}")
        by_height = sorted(faces, key=lambda f: -np.mean([model.vertices[v][2] for v in model.faces[f]]))
        for face, knuckle in zip(by_height, "AB"):
            finger_centre = np.mean([model.vertices[v] for v in model.faces[face]], axis=0)
            model.extrude([face], ring(side * 1.02, finger_centre, (0.022, 0.028), 0), f"knuckle{knuckle}{name}",
                          0.5)
            model.extrude([face], ring(side * 1.1, finger_centre, (0.02, 0.024), 0), f"knuckle{knuckle}{name}")
        parts.append(([(side * 0.16, 0, arm_z), (side * 0.55, 0, arm_z), (side * 0.8, 0, arm_z),
                       (side * 0.88, 0, arm_z)], [0.044, 0.037, 0.026, 0.026], 32))
        for dz in (0.0375, -0.0375):
            # The fingertips poke out of the cage's finger ends (x = ±1.1) by about their radius.
            parts.append(([(side * 0.88, 0, arm_z + dz), (side * 1.105, 0, arm_z + dz)], [0.013, 0.011], 16))
        # Legs: the bottom faces of the torso's half, down to the floor, then the foot forward and two toes.
        skeleton.add(f"hip{name}", "hips", (side * 0.1, 0, 0.9))
        skeleton.add(f"knee{name}", f"hip{name}", (side * 0.1, 0, 0.5))
        skeleton.add(f"ankle{name}", f"knee{name}", (side * 0.1, 0, 0.1))
        skeleton.add(f"toeA{name}", f"ankle{name}", (side * 0.075, -0.2, 0.05))
        skeleton.add(f"toeB{name}", f"ankle{name}", (side * 0.125, -0.2, 0.05))
        legs = model.find((side * 0.1, 0, 0.95), (0, 0, -1))[:2]
        leg_centre = (side * 0.1, 0.0, 0.95)
        model.extrude(legs, ring(0.86, leg_centre, (0.075, 0.08), 2), f"hip{name}", 0.5)
        model.extrude(legs, ring(0.5, leg_centre, (0.06, 0.065), 2), f"knee{name}", 0.5)
        model.extrude(legs, ring(0.12, leg_centre, (0.05, 0.055), 2), f"ankle{name}", 0.5)
        sides = model.extrude(legs, ring(0.0, leg_centre, (0.055, 0.06), 2), f"ankle{name}")
        front = [f for f in sides if np.mean([model.vertices[v][1] for v in model.faces[f]]) < -0.05]
        model.extrude(front, ring(-0.2, (side * 0.1, -0.055, 0.05), (0.055, 0.04), 1), f"ankle{name}")
        for face in front:
            corners = np.array([model.vertices[v] for v in model.faces[face]])
            toe = "A" if abs(corners[:, 0].mean()) < 0.1 else "B"
            model.extrude([face], ring(-0.29, corners.mean(axis=0), (0.02, 0.025), 1), f"toe{toe}{name}")
        parts.append(([(side * 0.1, 0, 1.0), (side * 0.1, 0, 0.5), (side * 0.1, 0, 0.06),
                       (side * 0.1, -0.17, 0.05)], [0.06, 0.045, 0.033, 0.03], 32))
        for dx in (-0.025, 0.025):
            # The toe tips poke out of the cage's toe ends (y = -0.29).
            parts.append(([(side * 0.1 + dx, -0.15, 0.05), (side * 0.1 + dx, -0.292, 0.05)], [0.014, 0.012], 16))
    # Tail: out of the middle of the back's lowest level, backwards, tapering to a point.
    back = model.find((0, 0.11, (z_levels[0] + z_levels[1]) / 2), (0, 1, 0))[:2]
    back_centre = np.mean([model.vertices[v] for f in back for v in model.faces[f]], axis=0)
    tail_z = back_centre[2]
    skeleton.add("tail1", "hips", (0, 0.11, tail_z))
    for k in range(2, 6):
        skeleton.add(f"tail{k}", f"tail{k - 1}", (0, 0.2 + 0.15 * (k - 2), tail_z))
    for k, (y, half) in enumerate(zip((0.2, 0.35, 0.5, 0.65, 0.8), (0.06, 0.045, 0.032, 0.02, 0.01)), start=1):
        model.extrude(back, ring(y, back_centre, (half, half), 1), f"tail{k}", 0.5 if k < 5 else 1.0)
    parts.append(([(0, 0.05, tail_z), (0, 0.8, tail_z)], [0.045, 0.004], 24))

    vertices, faces = [], []
    for path, radii, around in parts:
        v, f = tube(np.array(path, float), radii, spacing, around)
        faces.append(f + sum(len(x) for x in vertices))
        vertices.append(v)
    cage, cage_faces = model.arrays()
    joints = list(model.joint)

    def pose(rotations):
        return pose_vertices(skeleton, joints, cage, rotations)

    return np.vstack(vertices), np.concatenate(faces), cage, cage_faces, pose


def pose_vertices(skeleton, joints, vertices, rotations):
    """Every vertex carried by its joint, turned by its share of that joint's rotation."""
    posed = np.empty_like(vertices)
    cache = {}
    for index, (joint, share) in enumerate(joints):
        if (joint, share) not in cache:
            cache[joint, share] = skeleton.transforms(rotations, share, joint)[skeleton.names[joint]]
        rotation, shift = cache[joint, share]
        posed[index] = rotation @ vertices[index] + shift
    return posed


def mirrored(rotations):
    """Left-side rotations {name ending in L: (axis, degrees)} with their mirror images for the right side."""
    result = dict(rotations)
    for name, (axis, degrees) in rotations.items():
        if name.endswith("L"):
            # A mirror in x keeps the x component of a rotation axis and flips y and z (an axial vector).
            result[name[:-1] + "R"] = ((axis[0], -axis[1], -axis[2]), degrees)
    return result


# Poses of the figure: {joint: (axis, degrees)}, left side given, right mirrored.
FIGURE_POSES = {
    "walk": mirrored({
        "chest": ((1, 0, 0), -15), "neck": ((0, 0, 1), 35),
        "shoulderL": ((0, 1, 0), -55), "elbowL": ((0, 0, 1), 70), "wristL": ((1, 0, 0), 60),
        "knuckleAL": ((0, 0, 1), 60), "knuckleBL": ((0, 0, 1), 75),
        "hipL": ((1, 0, 0), -35), "kneeL": ((1, 0, 0), 60), "ankleL": ((1, 0, 0), -15),
        "toeAL": ((1, 0, 0), -30), "toeBL": ((1, 0, 0), -30),
        "tail2": ((1, 0, 0), 30), "tail3": ((1, 0, 0), 35), "tail4": ((1, 0, 0), 40), "tail5": ((1, 0, 0), 45),
    }),
    "crouch": mirrored({
        "chest": ((1, 0, 0), -30), "neck": ((0, 1, 0), 25),
        "shoulderL": ((0, 1, 0), -30), "elbowL": ((0, 0, 1), 110), "wristL": ((1, 0, 0), 100),
        "knuckleAL": ((0, 0, 1), 95), "knuckleBL": ((0, 0, 1), 95),
        "hipL": ((1, 0, 0), -80), "kneeL": ((1, 0, 0), 110), "ankleL": ((1, 0, 0), -35),
        "toeAL": ((1, 0, 0), -45), "toeBL": ((1, 0, 0), -20),
        "tail2": ((0, 0, 1), 50), "tail3": ((0, 0, 1), 55), "tail4": ((0, 0, 1), 60), "tail5": ((0, 0, 1), 70),
    }),
}


def tentacle(spacing=0.01, around=24, sides=6, rings=8, length=1.6, tip_out=0.008):
    """The tentacle scene: a tube tapering from radius 0.1 to 0.008 along z over ``length``, in a cage of ``rings``
    hexagonal rings tapering alike, closed by a point at each end; the tube's tip passes the cage's point by
    ``tip_out`` (it pokes out; negative: it stays inside).

    Returns
    -------
    vertices, faces, cage, cage_faces : as :func:`figure`
    pose : callable(curl degrees, twist degrees) -> (n, 3) float array
        The cage curled about the y axis, the curl growing towards the tip (so the tip curls most), and twisted.
    """
    mesh, faces = tube(np.array([(0, 0, 0.0), (0, 0, length + tip_out - 0.008)]), [0.1, 0.008], spacing, around)
    z = np.linspace(-0.12, length - 0.03, rings)
    radius = 0.15 + (0.03 - 0.15) * (z - z[0]) / (z[-1] - z[0])
    angle = 2 * np.pi * (np.arange(sides) + 0.5) / sides
    ring_vertices = np.concatenate([np.stack([r / np.cos(np.pi / sides) * np.cos(angle),
                                              r / np.cos(np.pi / sides) * np.sin(angle), np.full(sides, h)], axis=1)
                                    for h, r in zip(z, radius)])
    bottom, top = sides * rings, sides * rings + 1
    cage = np.vstack([ring_vertices, [(0, 0, z[0] - 0.08), (0, 0, length + 0.0)]])
    cage_faces = []
    for row in range(rings - 1):
        for k in range(sides):
            a, b = row * sides + k, row * sides + (k + 1) % sides
            cage_faces.append([a, b, b + sides, a + sides])
    cage_faces += [[bottom, (k + 1) % sides, k] for k in range(sides)]
    last = (rings - 1) * sides
    cage_faces += [[top, last + k, last + (k + 1) % sides] for k in range(sides)]
    low = z[0] - 0.08

    def pose(curl=270.0, twist=0.0):
        """The cage curled by ``curl`` degrees in all (the bend rate growing linearly along z) and twisted."""
        s = (cage[:, 2] - low) / (length - low)  # 0 at the base, 1 at the tip
        # Bend angle θ(s) = curl · s²: the rate grows along the tentacle. Integrate the centreline numerically.
        samples = np.linspace(0, 1, 2001)
        theta = np.radians(curl) * samples ** 2
        step = (length - low) / (len(samples) - 1)
        x_line = np.concatenate([[0], np.cumsum(np.sin(theta[1:]) * step)])
        z_line = np.concatenate([[0], np.cumsum(np.cos(theta[1:]) * step)]) + low
        th = np.interp(s, samples, theta)
        cx, cz = np.interp(s, samples, x_line), np.interp(s, samples, z_line)
        turn = np.radians(twist) * s
        x = cage[:, 0] * np.cos(turn) - cage[:, 1] * np.sin(turn)
        y = cage[:, 0] * np.sin(turn) + cage[:, 1] * np.cos(turn)
        return np.stack([cx + x * np.cos(th), y, cz - x * np.sin(th)], axis=1)

    return mesh, faces, cage, cage_faces, pose
