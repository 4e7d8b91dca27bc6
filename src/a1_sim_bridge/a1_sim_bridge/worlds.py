"""Ground models the A1 can be simulated on, selectable by name.

All worlds share the robot's frame conventions: world frame z up, the robot starts at the origin
facing +x. Friction values are *effective* foot-ground coefficients: the simulation sets the foot
links' lateral friction to 1.0, and PyBullet multiplies the two bodies' coefficients.

Every world stands on flat ground without end: PyBullet's plane.urdf is a 200 m square box, so
GroundTiles lays more of them around the robot once it comes within 25 m of an edge (a robot
walking at 1 m/s used to fall off at x = 100 m). Until then the world holds the one plane, which
keeps every run that stays within 75 m of the origin (any 20 s episode) exactly as before.
"""

from __future__ import annotations

import numpy as np

WORLD_NAMES = ("flat", "step", "rough", "soft", "slope")

# Soft ground (standing in for grass): compliant contact and lower friction.
SOFT_CONTACT_STIFFNESS = 2.0e4  # [N/m]
SOFT_CONTACT_DAMPING = 1.0e3  # [N s/m]
SOFT_FRICTION_SCALE = 0.6  # soft-ground friction = 0.6 x ground_friction

ROUGH_CELL_SIZE = 0.1  # heightfield resolution [m]
# Heights are vertex heights, equal over 2 x 2 vertex blocks: terrain of 0.1 m flat patches joined
# by 0.1 m slopes (up to about 22 degrees at the default 4 cm amplitude), not vertical steps.
ROUGH_BLOCK_CELLS = 2
ROUGH_EXTENT = 20.0  # side of the rough patch [m]
TILE_SIZE = 200.0  # side of plane.urdf's ground box [m]
TILE_GUARD = 75.0  # [m] from its tile's centre (25 m from the edge) the robot gets the 8 neighbouring tiles


class GroundTiles:
    """Flat ground without end: plane.urdf tiles on a TILE_SIZE grid, the 3 x 3 around the robot's
    tile once it is past TILE_GUARD from that tile's centre; tiles it left behind are moved ahead.
    A tile is only ever moved when the robot is at least a tile away from it."""

    def __init__(self, client, centre_tile: int, friction: float, soft: bool) -> None:
        self._client, self._friction, self._soft = client, friction, soft
        self._tiles = {(0, 0): centre_tile}
        self._index = (0, 0)
        self._grown = False

    def follow(self, x: float, y: float) -> None:
        """Lay the ground around the robot's base position (world x, y [m]); cheap when nothing changes."""
        index = (round(x / TILE_SIZE), round(y / TILE_SIZE))
        if index == self._index and (self._grown or max(abs(x - index[0] * TILE_SIZE),
                                                        abs(y - index[1] * TILE_SIZE)) < TILE_GUARD):
            return
        self._index, self._grown = index, True
        wanted = {(index[0] + i, index[1] + j) for i in (-1, 0, 1) for j in (-1, 0, 1)}
        spare = [self._tiles.pop(k) for k in list(self._tiles) if k not in wanted]
        for i, j in sorted(wanted - set(self._tiles)):
            body = spare.pop() if spare else ground_tile(self._client, self._friction, self._soft)
            self._client.resetBasePositionAndOrientation(body, [i * TILE_SIZE, j * TILE_SIZE, 0.0], [0, 0, 0, 1])
            self._tiles[(i, j)] = body


def ground_tile(client, friction: float, soft: bool) -> int:
    """One plane.urdf ground box (top face at z = 0) with the world's ground contact properties."""
    plane = client.loadURDF("plane.urdf")
    if soft:
        client.changeDynamics(plane, -1, contactStiffness=SOFT_CONTACT_STIFFNESS, contactDamping=SOFT_CONTACT_DAMPING)
    client.changeDynamics(plane, -1, lateralFriction=friction, restitution=0.0)
    return plane


def build_world(client, name: str, *, ground_friction: float, rng: np.random.Generator,
                step_height: float, step_distance: float, rough_amplitude: float,
                slope_angle: float) -> tuple[list[int], float, GroundTiles]:
    """Create the ground bodies of world ``name`` in ``client``.

    Returns the body ids, the ground height under the origin [m], where the robot is placed, and the
    ground tiles, which the simulation tells where the robot is.
    """
    if name not in WORLD_NAMES:
        raise ValueError(f"world must be one of {WORLD_NAMES}, got {name!r}")
    soft = name == "soft"
    friction = ground_friction * SOFT_FRICTION_SCALE if soft else ground_friction
    plane = ground_tile(client, friction, soft)
    bodies = [plane]
    origin_height = 0.0
    if name == "step":
        length, width = 5.0, 4.0
        half = [length / 2, width / 2, step_height / 2]
        shape = client.createCollisionShape(client.GEOM_BOX, halfExtents=half)
        visual = client.createVisualShape(client.GEOM_BOX, halfExtents=half, rgbaColor=[0.6, 0.6, 0.6, 1])
        bodies.append(client.createMultiBody(0, shape, visual,
                                             [step_distance + length / 2, 0.0, step_height / 2]))
    elif name == "slope":
        length, width, thickness = 10.0, 4.0, 0.1
        half = [length / 2, width / 2, thickness / 2]
        shape = client.createCollisionShape(client.GEOM_BOX, halfExtents=half)
        visual = client.createVisualShape(client.GEOM_BOX, halfExtents=half, rgbaColor=[0.6, 0.6, 0.6, 1])
        # The ramp's top surface starts at ground level 1 m ahead and rises along +x.
        start = 1.0
        centre_x = start + (length / 2) * np.cos(slope_angle) + (thickness / 2) * np.sin(slope_angle)
        centre_z = (length / 2) * np.sin(slope_angle) - (thickness / 2) * np.cos(slope_angle)
        orientation = client.getQuaternionFromEuler([0.0, -slope_angle, 0.0])
        bodies.append(client.createMultiBody(0, shape, visual, [centre_x, 0.0, centre_z], orientation))
    elif name == "rough":
        cells = round(ROUGH_EXTENT / ROUGH_CELL_SIZE)
        blocks = cells // ROUGH_BLOCK_CELLS
        coarse = rng.uniform(0.0, rough_amplitude, size=(blocks, blocks))
        heights = np.kron(coarse, np.ones((ROUGH_BLOCK_CELLS, ROUGH_BLOCK_CELLS)))
        shape = client.createCollisionShape(
            client.GEOM_HEIGHTFIELD, meshScale=[ROUGH_CELL_SIZE, ROUGH_CELL_SIZE, 1.0],
            heightfieldData=heights.ravel().tolist(), numHeightfieldRows=cells,
            numHeightfieldColumns=cells)
        # Bullet centres a heightfield vertically on the middle of its height range.
        centre_z = 0.5 * (heights.max() + heights.min())
        bodies.append(client.createMultiBody(0, shape, -1, [0.0, 0.0, centre_z]))
        origin_height = float(heights.max())  # place the robot above the highest cell
    for body in bodies[1:]:
        client.changeDynamics(body, -1, lateralFriction=friction, restitution=0.0)
    return bodies, origin_height, GroundTiles(client, plane, friction, soft)
