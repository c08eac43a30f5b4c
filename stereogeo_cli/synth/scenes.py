"""Scenes with metric scale (world: x east, y north, z up, metres), built as triangle lists.

Indoor: rooms (3–12 m) and corridors with doors, windows (which show the panorama at infinity),
pictures and furniture standing on the floor. Outdoor: streets with pavements, building blocks 5–40 m
tall, cars, poles and street furniture; and open ground (plazas, car parks). Close range: a cluttered desk
and shelves seen from 0.35–1.5 m. The rig is placed first and objects keep clear of both cameras, so no
camera is ever inside or touching geometry.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from stereogeo_cli.synth.rigs import Rig, RigSample
from stereogeo_cli.synth.textures import Material

VERTEX_FLOATS = 13  # position 3, normal 3, uv 2, layer 1, tint 3, mirror 1
SCENE_KINDS = ("room", "corridor", "desk", "street", "open")
_CLEARANCE = 0.3  # metres between a camera centre and any surface
_UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


@dataclass(frozen=True)
class MaterialRef:
    """A pool layer as used on one surface: its tint and the metres one copy of the texture covers."""

    layer: int
    tint: tuple[float, float, float]
    tile: tuple[float, float]
    mirror: bool


class MaterialIndex:
    """Which pool layers can cover which kind of surface (metadata only: usable without OpenGL)."""

    def __init__(self, pool: list[Material]):
        self.tags: dict[str, list[int]] = {}
        self.tiles = [m.tile_m for m in pool]
        self.mirror = [m.mirror for m in pool]
        for i, material in enumerate(pool):
            for tag in material.tags:
                self.tags.setdefault(tag, []).append(i)

    def pick(
        self, rng: np.random.Generator, tag: str, tile: tuple[float, float] | None = None
    ) -> MaterialRef:
        choices = self.tags.get(tag) or self.tags["object"]
        layer = int(choices[rng.integers(len(choices))])
        tint = tuple(float(v) for v in np.exp(rng.normal(0.0, 0.08, 3)) * rng.uniform(0.85, 1.1))
        scale = float(np.exp(rng.normal(0.0, 0.2)))
        base = self.tiles[layer] if tile is None else tile
        return MaterialRef(layer, tint, (base[0] * scale, base[1] * scale), self.mirror[layer])


def _material_row(material: MaterialRef) -> tuple:
    return (material.layer, *material.tint, *material.tile, 1.0 if material.mirror else 0.0)


def _quad_vertices(q: np.ndarray) -> np.ndarray:
    """Quads [Q x 21] (p0 3, e_u 3, e_v 3, normal 3 or 0, uv offset 2, material 7) → vertices [6Q x 13]."""
    p0, e_u, e_v, n = q[:, 0:3], q[:, 3:6], q[:, 6:9], q[:, 9:12]
    uv_offset, layer, tint, tile, mirror = q[:, 12:14], q[:, 14], q[:, 15:18], q[:, 18:20], q[:, 20]
    missing = ~np.any(n != 0, axis=1)
    n[missing] = np.cross(e_v[missing], e_u[missing])
    n = n / np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
    lengths = np.sqrt(np.stack([np.einsum("ij,ij->i", e_u, e_u), np.einsum("ij,ij->i", e_v, e_v)], 1))
    corners = np.stack([p0, p0 + e_u, p0 + e_u + e_v, p0 + e_v], axis=1)  # [Q x 4 x 3]
    uv = _UNIT_SQUARE[None] * (lengths / tile)[:, None] + uv_offset[:, None]
    idx = [0, 1, 2, 0, 2, 3]
    v = np.empty((len(q), 6, VERTEX_FLOATS))
    v[:, :, 0:3] = corners[:, idx]
    v[:, :, 3:6] = n[:, None]
    v[:, :, 6:8] = uv[:, idx]
    v[:, :, 8] = layer[:, None]
    v[:, :, 9:12] = tint[:, None]
    v[:, :, 12] = mirror[:, None]
    return v.reshape(-1, VERTEX_FLOATS)


def _box_quads(b: np.ndarray) -> np.ndarray:
    """Boxes [B x 22] (cx, cy, z0, yaw, length, width, height, facade, sides 7, top 7) → quads [5B x 21]."""
    cx, cy, z0, yaw, length, width, height, facade = (b[:, k] for k in range(8))
    c, s = np.cos(yaw), np.sin(yaw)
    ax = np.stack([c, s, np.zeros_like(c)], 1) * (length / 2)[:, None]
    ay = np.stack([-s, c, np.zeros_like(c)], 1) * (width / 2)[:, None]
    base = np.stack([cx, cy, z0], 1)
    signs = np.array([(-1, -1), (1, -1), (1, 1), (-1, 1)], float)
    corners = (
        base[:, None] + signs[None, :, :1] * ax[:, None] + signs[None, :, 1:] * ay[:, None]
    )  # [B x 4 x 3]
    edges = np.roll(corners, -1, axis=1) - corners
    up = np.zeros((len(b), 3))
    up[:, 2] = height
    sides, top = b[:, 8:15], b[:, 15:22]
    tile_u, tile_v = sides[:, 4], sides[:, 5]
    steps = np.sqrt(np.einsum("bkj,bkj->bk", edges, edges)) / tile_u[:, None]
    u_off = np.concatenate([np.zeros((len(b), 1)), np.cumsum(steps, axis=1)[:, :-1]], axis=1)
    v_off = np.where(facade > 0, -(z0 + height) / tile_v, 0.0)
    q = np.zeros((len(b), 5, 21))
    q[:, :4, 0:3] = corners + up[:, None]
    q[:, :4, 3:6] = edges
    q[:, :4, 6:9] = -up[:, None]
    q[:, :4, 12] = u_off
    q[:, :4, 13] = v_off[:, None]
    q[:, :4, 14:21] = sides[:, None]
    q[:, 4, 0:3] = corners[:, 0] + up
    q[:, 4, 3:6] = corners[:, 3] - corners[:, 0]
    q[:, 4, 6:9] = corners[:, 1] - corners[:, 0]
    q[:, 4, 11] = 1.0
    q[:, 4, 14:21] = top
    return q.reshape(-1, 21)


@dataclass
class MeshBuilder:
    """Collects textured quads and boxes (built into triangles in one vectorised pass by :meth:`arrays`)
    and environment triangles (windows showing the panorama)."""

    quad_rows: list[tuple] = field(default_factory=list)
    box_rows: list[tuple] = field(default_factory=list)
    windows: list[np.ndarray] = field(default_factory=list)

    def quad(self, p0, e_u, e_v, material: MaterialRef, uv_offset=(0.0, 0.0), normal=None) -> None:
        """The parallelogram p0, p0+e_u, p0+e_u+e_v, p0+e_v; the texture's u runs along e_u and v along e_v.

        For vertical faces pass e_v pointing down so the texture stands upright. UVs are in copies of the
        texture (metres / tile), so no texture is stretched. The normal defaults to e_v × e_u.
        """
        n = (0.0, 0.0, 0.0) if normal is None else tuple(normal)
        self.quad_rows.append((*p0, *e_u, *e_v, *n, *uv_offset, *_material_row(material)))

    def window(self, p0, e_u, e_v) -> None:
        p0, e_u, e_v = (np.asarray(a, dtype=np.float64) for a in (p0, e_u, e_v))
        corners = np.array([p0, p0 + e_u, p0 + e_u + e_v, p0 + e_v])
        self.windows.append(corners[[0, 1, 2, 0, 2, 3]])

    def box(
        self,
        center_xy,
        size,
        z0: float,
        yaw: float,
        sides: MaterialRef,
        top: MaterialRef | None = None,
        facade_phase: bool = False,
    ) -> None:
        """An upright box standing at height z0: size = (length along yaw, width, height), metres.

        With ``facade_phase`` the side textures are aligned to the ground (storeys line up across buildings).
        """
        self.box_rows.append(
            (
                center_xy[0],
                center_xy[1],
                z0,
                yaw,
                *size,
                1.0 if facade_phase else 0.0,
                *_material_row(sides),
                *_material_row(top or sides),
            )
        )

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        parts = []
        if self.quad_rows:
            parts.append(np.array(self.quad_rows, dtype=float))
        if self.box_rows:
            parts.append(_box_quads(np.array(self.box_rows, dtype=float)))
        surfaces = (
            _quad_vertices(np.concatenate(parts)).astype(np.float32)
            if parts
            else np.zeros((0, 13), np.float32)
        )
        windows = (
            np.concatenate(self.windows).astype(np.float32) if self.windows else np.zeros((0, 3), np.float32)
        )
        return surfaces, windows


@dataclass(frozen=True)
class Lighting:
    ambient: float
    strength: float
    direction: tuple[float, float, float]  # towards the sun (outdoor), unit
    point: tuple[float, float, float] | None  # a lamp position (indoor), metres
    falloff: float  # metres: lamp intensity halves at this distance
    grime: float = 0.8  # strength of the dirt / wear overlay on all surfaces


@dataclass(frozen=True)
class Scene:
    """A scene ready to draw: triangles [N x 13] and window triangles [M x 3] (float32), and its rig."""

    kind: str
    surfaces: np.ndarray
    windows: np.ndarray
    lighting: Lighting
    sky_yaw: float  # panorama rotation about the vertical, in turns
    near: float
    far: float
    rig: Rig
    # where traffic may move (streets and roads): {"lanes": [(path [P x 2] world xy in the direction of
    # travel, z0)], "walks": [(path, z0)]}; None elsewhere (traffic.py then draws free straight paths)
    traffic: dict | None = None
    movers: tuple = ()  # traffic.Mover: objects that move on their own between frames (sequences only)


def _box_distance(point: np.ndarray, center_xy, size, z0: float, yaw: float) -> float:
    c, s = np.cos(yaw), np.sin(yaw)
    d = point[:2] - np.asarray(center_xy, dtype=float)
    local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], point[2] - (z0 + size[2] / 2)])
    q = np.abs(local) - np.array(size) / 2
    return float(np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0))


class _Placer:
    """Adds boxes only where they keep clear of the cameras (and optionally of each other)."""

    def __init__(self, mesh: MeshBuilder, rig: Rig):
        self.mesh = mesh
        self.cameras = [rig.left.center, rig.right.center]
        self.footprints: list[tuple[np.ndarray, float]] = []

    def clear(self, center_xy, size, z0, yaw, margin=_CLEARANCE) -> bool:
        return all(_box_distance(c, center_xy, size, z0, yaw) > margin for c in self.cameras)

    def free(self, center_xy, size) -> bool:
        radius = 0.5 * float(np.hypot(size[0], size[1]))
        p = np.asarray(center_xy, dtype=float)
        return all(np.linalg.norm(p - q) > radius + r for q, r in self.footprints)

    def box(self, center_xy, size, z0, yaw, sides, top=None, exclusive=True, **kw) -> bool:
        if not self.clear(center_xy, size, z0, yaw) or (exclusive and not self.free(center_xy, size)):
            return False
        self.mesh.box(center_xy, size, z0, yaw, sides, top, **kw)
        if exclusive:
            self.footprints.append(
                (np.asarray(center_xy, dtype=float), 0.5 * float(np.hypot(size[0], size[1])))
            )
        return True


def _lighting_outdoor(rng) -> Lighting:
    elevation, azimuth = rng.uniform(np.radians(15), np.radians(70)), rng.uniform(0, 2 * np.pi)
    d = (np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation))
    return Lighting(
        float(rng.uniform(0.4, 0.65)),
        float(rng.uniform(0.3, 0.6)),
        d,
        None,
        1.0,
        float(rng.uniform(0.3, 0.9)),
    )


def _lighting_indoor(rng, lamp) -> Lighting:
    return Lighting(
        float(rng.uniform(0.45, 0.7)),
        float(rng.uniform(0.3, 0.6)),
        (0.0, 0.0, 1.0),
        tuple(lamp),
        float(rng.uniform(2.0, 6.0)),
        float(rng.uniform(0.25, 0.7)),
    )


def _ray_to_walls(origin: np.ndarray, direction_xy: np.ndarray, half: np.ndarray) -> float:
    """Distance from a point inside the box [-half, half] (x, y) to its walls along a horizontal direction."""
    t = np.inf
    for k in range(2):
        if abs(direction_xy[k]) > 1e-9:
            wall = half[k] if direction_xy[k] > 0 else -half[k]
            t = min(t, (wall - origin[k]) / direction_xy[k])
    return float(t)


def _place_rig_in_box(rng, rig_sample: RigSample, half: np.ndarray, z_range, corridor: bool):
    """A rig inside the room [-half, half] with both cameras clear of the walls and a view of ≥ 1.5 m."""
    best = None
    for _ in range(30):
        margin = _CLEARANCE + 0.2
        center = np.array(
            [
                rng.uniform(-half[0] + margin, half[0] - margin),
                rng.uniform(-half[1] + margin, half[1] - margin),
                rng.uniform(*z_range),
            ]
        )
        if corridor and rng.random() < 0.75:
            yaw = (0.0 if rng.random() < 0.5 else np.pi) + rng.normal(0, 0.35)
        else:
            yaw = rng.uniform(0, 2 * np.pi)
        rig = rig_sample.place(center, yaw)
        inside = all(
            np.all(np.abs(c.center[:2]) < half - _CLEARANCE)
            and z_range[0] - 0.2 < c.center[2] < z_range[1] + 0.2
            for c in (rig.left, rig.right)
        )
        if not inside:
            continue
        forward = rig.left.R_wc.T @ np.array([0.0, 0.0, 1.0])
        reach = _ray_to_walls(center, forward[:2] / max(np.linalg.norm(forward[:2]), 1e-9), half)
        if reach >= min(2.5, 0.8 * float(np.min(half))):
            return rig
        best = rig if best is None else best
    if best is None:  # a tiny room and a wide rig: fall back to the middle of the room
        best = rig_sample.place(np.array([0.0, 0.0, float(np.mean(z_range))]), 0.0)
    return best


def build_room(
    rng, rig_sample: RigSample, materials: MaterialIndex, corridor: bool = False, objects: bool = True
):
    if corridor:
        size = np.array([rng.uniform(10, 40), rng.uniform(1.6, 3.2), rng.uniform(2.4, 3.5)])
    else:
        size = np.array([rng.uniform(3, 12), rng.uniform(3, 12), rng.uniform(2.4, 4.0)])
        size[2] += rng.uniform(0, 2.5) * (size[0] * size[1] > 60)  # large halls are taller
    needed = rig_sample.baseline + 2 * (_CLEARANCE + 0.25)
    size[:2] = np.maximum(size[:2], needed)
    half = size[:2] / 2
    height = float(size[2])
    rig = _place_rig_in_box(rng, rig_sample, half, (0.3, min(2.0, height - 0.5)), corridor)
    mesh = MeshBuilder()
    _room_shell(rng, mesh, materials, -half, half, height, corridor)
    placer = _Placer(mesh, rig)
    if objects:
        _furnish(rng, placer, materials, half, height, corridor)
    lamp = (rng.uniform(-half[0], half[0]) * 0.6, rng.uniform(-half[1], half[1]) * 0.6, height - 0.2)
    surfaces, windows = mesh.arrays()
    kind = "corridor" if corridor else "room"
    return Scene(kind, surfaces, windows, _lighting_indoor(rng, lamp), float(rng.random()), 0.05, 200.0, rig)


def _room_shell(
    rng, mesh: MeshBuilder, materials: MaterialIndex, lo, hi, height: float, corridor: bool
) -> None:
    """Floor, ceiling, four decorated walls and ceiling lights of the room [lo, hi] (x, y) × [0, height]."""
    wall = materials.pick(rng, "wall")
    floor, ceiling = materials.pick(rng, "floor"), materials.pick(rng, "ceiling")
    (x0, y0), (x1, y1) = lo, hi
    mesh.quad((x0, y0, 0), (x1 - x0, 0, 0), (0, y1 - y0, 0), floor, normal=(0, 0, 1))
    mesh.quad((x0, y0, height), (0, y1 - y0, 0), (x1 - x0, 0, 0), ceiling, normal=(0, 0, -1))
    # walls, seen from inside: (top-left corner, direction along the wall, inward normal)
    walls = [
        ((x0, y0), (1, 0), (0, 1)),
        ((x1, y0), (0, 1), (-1, 0)),
        ((x1, y1), (-1, 0), (0, -1)),
        ((x0, y1), (0, -1), (1, 0)),
    ]
    for k, (start, along, inward) in enumerate(walls):
        length = (x1 - x0) if k % 2 == 0 else (y1 - y0)
        start3, along3, in3 = np.array([*start, height]), np.array([*along, 0.0]), np.array([*inward, 0.0])
        mesh.quad(start3, along3 * length, (0, 0, -height), wall, uv_offset=(k * 0.37, 0), normal=in3)
        _decorate_wall(rng, mesh, materials, start3, along3, in3, length, height, corridor)
    _ceiling_lights(rng, mesh, materials, lo, hi, height)


def _ceiling_lights(rng, mesh: MeshBuilder, materials: MaterialIndex, lo, hi, height) -> None:
    """Bright light panels in a grid just under the ceiling of the room [lo, hi]."""
    panel = materials.pick(rng, "pole", tile=(1.0, 1.0))
    panel = replace(panel, tint=(2.2, 2.2, 2.1))
    w, d = (0.6, 0.6) if rng.random() < 0.5 else (1.2, 0.3)
    spacing = rng.uniform(1.8, 3.5)
    extent = np.asarray(hi, dtype=float) - np.asarray(lo, dtype=float)
    nx, ny = max(1, int(extent[0] / spacing)), max(1, int(extent[1] / spacing))
    xs = (np.arange(nx) + 0.5) * extent[0] / nx + lo[0]
    ys = (np.arange(ny) + 0.5) * extent[1] / ny + lo[1]
    for x in xs:
        for y in ys:
            mesh.quad((x - w / 2, y - d / 2, height - 0.01), (0, d, 0), (w, 0, 0), panel, normal=(0, 0, -1))


def _decorate_wall(rng, mesh, materials, start, along, inward, length, height, corridor) -> None:
    """Doors, windows and pictures on one wall, not overlapping, 1–2 cm in front of it."""
    used: list[tuple[float, float]] = []

    def slot(width: float) -> float | None:
        for _ in range(8):
            a = rng.uniform(0.2, length - width - 0.2) if length > width + 0.4 else None
            if a is not None and all(a + width < u0 - 0.2 or a > u1 + 0.2 for u0, u1 in used):
                used.append((a, a + width))
                return a
        return None

    per_wall = max(1, int(length / (3.5 if corridor else 5.0)))
    for _ in range(int(rng.integers(0, per_wall + 1))):
        w, h = rng.uniform(0.8, 1.0), rng.uniform(2.0, 2.2)
        a = slot(w)
        if a is not None and h < height - 0.1:
            p0 = start + along * a + np.array([0, 0, h]) + inward * 0.015
            mesh.quad(p0, along * w, (0, 0, -h), materials.pick(rng, "door", tile=(w, h)), normal=inward)
    if not corridor or rng.random() < 0.3:
        for _ in range(int(rng.integers(0, per_wall + 1))):
            w, h, sill = rng.uniform(0.8, 2.2), rng.uniform(1.0, 1.6), rng.uniform(0.8, 1.0)
            a = slot(w + 0.2)
            if a is not None and sill + h < height - 0.15:
                frame = materials.pick(rng, "pole", tile=(1.0, 1.0))
                p0 = start + along * a + np.array([0, 0, sill + h + 0.1]) + inward * 0.01
                mesh.quad(p0, along * (w + 0.2), (0, 0, -(h + 0.2)), frame, normal=inward)
                mesh.window(p0 + along * 0.1 + np.array([0, 0, -0.1]) + inward * 0.01, along * w, (0, 0, -h))
    if rng.random() < 0.6:  # skirting board
        board = rng.uniform(0.06, 0.12)
        mesh.quad(
            start + np.array([0, 0, board]) + inward * 0.008,
            along * length,
            (0, 0, -board),
            materials.pick(rng, "object", tile=(1.0, 1.0)),
            normal=inward,
        )
    for _ in range(int(rng.integers(0, 2 + per_wall))):
        w = rng.uniform(0.4, 1.5)
        h = w * rng.uniform(0.6, 1.4)
        a = slot(w)
        bottom = rng.uniform(1.0, 1.5)
        if a is not None and bottom + h < height - 0.1:
            p0 = start + along * a + np.array([0, 0, bottom + h]) + inward * 0.02
            mesh.quad(p0, along * w, (0, 0, -h), materials.pick(rng, "poster", tile=(w, h)), normal=inward)


def _furnish(rng, placer: _Placer, materials, half, height, corridor) -> None:
    count = int(rng.integers(0, 5)) if corridor else int(rng.integers(4, 14))
    for _ in range(count):
        kind = rng.choice(["table", "cabinet", "sofa", "box"], p=[0.3, 0.3, 0.2, 0.2])
        if kind == "table":
            size = (rng.uniform(0.8, 2.0), rng.uniform(0.6, 1.0), rng.uniform(0.7, 0.78))
        elif kind == "cabinet":
            size = (rng.uniform(0.6, 2.0), rng.uniform(0.35, 0.6), rng.uniform(0.8, min(2.3, height - 0.2)))
        elif kind == "sofa":
            size = (rng.uniform(1.5, 2.4), rng.uniform(0.8, 1.0), rng.uniform(0.4, 0.5))
        else:
            size = tuple(rng.uniform(0.3, 1.0, 3))
        yaw = float(rng.choice([0.0, np.pi / 2])) + (rng.normal(0, 0.3) if rng.random() < 0.3 else 0.0)
        reach = 0.5 * np.hypot(size[0], size[1])
        if np.any(half < reach + 0.05):
            continue
        if kind == "cabinet" and rng.random() < 0.7:  # against a wall
            side = int(rng.integers(4))
            yaw = [0.0, np.pi / 2, 0.0, np.pi / 2][side]
            along_half, off_half = (half[0], half[1]) if side % 2 == 0 else (half[1], half[0])
            if along_half < size[0] / 2 + 0.05:
                continue
            along = rng.uniform(-1, 1) * (along_half - size[0] / 2 - 0.05)
            off = off_half - size[1] / 2 - 0.03
            xy = [(along, -off), (off, along), (along, off), (-off, along)][side]
        else:
            xy = (
                rng.uniform(-half[0] + reach, half[0] - reach),
                rng.uniform(-half[1] + reach, half[1] - reach),
            )
        sides = materials.pick(rng, "object")
        if kind == "table":
            top = (size[0], size[1], 0.05)
            if not placer.clear(xy, size, 0.0, yaw) or not placer.free(xy, size):
                continue
            placer.box(xy, top, size[2] - 0.05, yaw, sides, exclusive=False)
            c, s = np.cos(yaw), np.sin(yaw)
            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                lx, ly = sx * (size[0] / 2 - 0.06), sy * (size[1] / 2 - 0.06)
                leg_xy = (xy[0] + c * lx - s * ly, xy[1] + s * lx + c * ly)
                placer.box(leg_xy, (0.05, 0.05, size[2] - 0.05), 0.0, yaw, sides, exclusive=False)
            placer.footprints.append((np.asarray(xy, dtype=float), 0.5 * float(np.hypot(size[0], size[1]))))
            for _ in range(int(rng.integers(0, 5))):  # books, boxes, appliances on the table
                item = tuple(rng.uniform(0.08, 0.4, 3))
                lx, ly = (
                    rng.uniform(-0.5, 0.5) * (size[0] - item[0]),
                    rng.uniform(-0.5, 0.5) * (size[1] - item[1]),
                )
                item_xy = (xy[0] + c * lx - s * ly, xy[1] + s * lx + c * ly)
                look = materials.pick(rng, "poster" if rng.random() < 0.5 else "object")
                placer.box(item_xy, item, size[2], yaw + rng.normal(0, 0.3), look, exclusive=False)
        else:
            placer.box(xy, size, 0.0, yaw, sides)


def build_desk(
    rng, rig_sample: RigSample, materials: MaterialIndex, objects: bool = True, baseline_m=(0.05, 0.8)
) -> Scene:
    """Close range: a cluttered desk or workbench against a room's wall, and shelves above it, seen from
    0.35–1.5 m. The baseline is redrawn log-uniform within ``baseline_m`` up to a quarter of that distance,
    as on hand-held and tabletop rigs."""
    distance = float(np.exp(rng.uniform(np.log(0.35), np.log(1.5))))  # camera to the middle of the desk
    lo, hi = baseline_m
    baseline = float(np.exp(rng.uniform(np.log(lo), np.log(np.clip(0.25 * distance, lo, hi)))))
    rig_sample = replace(rig_sample, offset=rig_sample.offset * baseline / rig_sample.baseline)
    if rig_sample.pitch > 0 and rng.random() < 0.75:  # one looks down at a desk more often than up
        rig_sample = replace(rig_sample, pitch=-rig_sample.pitch)
    top_z = rng.uniform(0.7, 0.95) if rng.random() < 0.8 else rng.uniform(0.4, 0.55)  # desk or low table
    desk = np.array([rng.uniform(1.0, 2.4), rng.uniform(0.5, 0.9)])  # along the wall, away from it
    size = np.array([rng.uniform(2.5, 6.0), rng.uniform(2.5, 6.0), rng.uniform(2.4, 3.2)])
    size[0] = max(size[0], desk[0] + 0.4)
    size[1] = max(size[1], desk[1] + distance + 1.2)
    half, height = size[:2] / 2, float(size[2])
    desk_xy = np.array([rng.uniform(-1, 1) * (half[0] - desk[0] / 2 - 0.1), -half[1] + desk[1] / 2 + 0.01])
    # the left camera above and in front of the desk, facing the wall (-y) within ±25°
    yaw = -np.pi / 2 + float(np.clip(rng.normal(0.0, 0.25), -0.45, 0.45))
    rise = rng.uniform(0.1, 0.75) * distance + 0.1  # above the desk top
    ahead = np.sqrt(max(distance**2 - rise**2, 0.0))
    center = np.array([desk_xy[0] - ahead * np.cos(yaw), desk_xy[1] - ahead * np.sin(yaw), top_z + rise])
    rig = rig_sample.place(center, yaw)
    for _ in range(20):  # step back and up until both cameras keep clear of the desk and its wall
        if all(
            _box_distance(c.center, desk_xy, (*desk, top_z), 0.0, 0.0) > _CLEARANCE
            and c.center[1] > -half[1] + _CLEARANCE
            for c in (rig.left, rig.right)
        ):
            break
        center = center - 0.05 * np.array([np.cos(yaw), np.sin(yaw), -1.0])
        rig = rig_sample.place(center, yaw)
    # a camera far to the side, at the back or high up (rare): move those walls or the ceiling out
    centers = np.array([rig.left.center, rig.right.center])
    room_lo = np.array([min(-half[0], centers[:, 0].min() - _CLEARANCE - 0.05), -half[1]])
    room_hi = np.maximum(half, centers[:, :2].max(axis=0) + _CLEARANCE + 0.05)
    height = max(height, float(centers[:, 2].max()) + _CLEARANCE + 0.05)
    mesh = MeshBuilder()
    _room_shell(rng, mesh, materials, room_lo, room_hi, height, corridor=False)
    placer = _Placer(mesh, rig)
    wood = materials.pick(rng, "object", tile=(rng.uniform(0.4, 1.2),) * 2)
    placer.box(desk_xy, (*desk, 0.04), top_z - 0.04, 0.0, wood, exclusive=False)
    placer.footprints.append((desk_xy, 0.5 * float(np.hypot(*desk))))
    for sx in (-1, 1):  # side panels
        placer.box(
            (desk_xy[0] + sx * (desk[0] / 2 - 0.02), desk_xy[1]),
            (0.03, desk[1], top_z - 0.04),
            0.0,
            0.0,
            wood,
            exclusive=False,
        )
    if objects:
        _clutter(rng, placer, materials, desk_xy, desk, top_z, count=int(rng.integers(6, 25)))
        z = top_z + rng.uniform(0.3, 0.5)
        for _ in range(int(rng.integers(0, 4))):  # shelves on the wall above the desk
            if z > height - 0.3:
                break
            shelf = np.array([desk[0] * rng.uniform(0.5, 1.0), rng.uniform(0.18, 0.32)])
            shelf_xy = np.array(
                [desk_xy[0] + rng.uniform(-0.5, 0.5) * (desk[0] - shelf[0]), -half[1] + shelf[1] / 2 + 0.005]
            )
            if placer.box(shelf_xy, (*shelf, 0.025), z - 0.025, 0.0, wood, exclusive=False):
                _clutter(rng, placer, materials, shelf_xy, shelf, z, count=int(rng.integers(3, 12)))
            z += rng.uniform(0.3, 0.45)
        _furnish(rng, placer, materials, half, height, corridor=False)
    lamp = (
        desk_xy[0] + rng.uniform(-0.5, 0.5),
        desk_xy[1] + rng.uniform(0.2, 1.0),
        top_z + rng.uniform(0.5, 1.5),
    )
    surfaces, windows = mesh.arrays()
    return Scene(
        "desk", surfaces, windows, _lighting_indoor(rng, lamp), float(rng.random()), 0.02, 200.0, rig
    )


def _clutter(rng, placer: _Placer, materials, xy, extent, z0: float, count: int) -> None:
    """Books, boxes, cups and devices (3–35 cm) standing on the surface of size ``extent`` centred at xy,
    some stacked; small items get textures sized to them, so their detail survives at close range."""
    for _ in range(count):
        item = np.array([rng.uniform(0.03, 0.35), rng.uniform(0.03, 0.3), rng.uniform(0.02, 0.3)])
        item[:2] = np.minimum(item[:2], np.asarray(extent) * 0.9)
        at = np.asarray(xy) + rng.uniform(-0.5, 0.5, 2) * (np.asarray(extent) - item[:2])
        look = materials.pick(
            rng,
            "poster" if rng.random() < 0.5 else "object",
            tile=tuple(float(v) for v in np.max(item[:2]) * rng.uniform(0.7, 2.0, 2)),
        )
        yaw = float(rng.normal(0.0, 0.4))
        if placer.box(at, tuple(item), z0, yaw, look, exclusive=False) and rng.random() < 0.25:
            top = item * np.array([rng.uniform(0.5, 1.0), rng.uniform(0.5, 1.0), rng.uniform(0.3, 1.0)])
            placer.box(at, tuple(top), z0 + item[2], yaw + rng.normal(0, 0.2), look, exclusive=False)


def build_street(rng, rig_sample: RigSample, materials: MaterialIndex, objects: bool = True) -> Scene:
    road = rng.uniform(6.0, 14.0)
    pavement = rng.uniform(2.0, 5.0)
    kerb = rng.uniform(0.1, 0.18)
    far = 3000.0
    front = road / 2 + pavement
    # the rig: on the road or a pavement, mostly at car / robot / eye height
    for _ in range(30):
        y = rng.uniform(-front + 0.8, front - 0.8)
        base = kerb if abs(y) > road / 2 else 0.0
        h = rng.uniform(0.4, 2.2) if rng.random() < 0.75 else rng.uniform(2.2, 6.0)
        yaw = (
            (rng.choice([0.0, np.pi]) + rng.normal(0, 0.4))
            if rng.random() < 0.5
            else rng.uniform(0, 2 * np.pi)
        )
        rig = rig_sample.place(np.array([rng.uniform(-20, 20), y, base + h]), float(yaw))
        if all(
            abs(c.center[1]) < front - 0.4
            and c.center[2] > (kerb if abs(c.center[1]) > road / 2 - 0.3 else 0) + 0.25
            for c in (rig.left, rig.right)
        ):
            break
    mesh = MeshBuilder()
    asphalt, ground = materials.pick(rng, "road"), materials.pick(rng, "ground")
    mesh.quad((-far, -road / 2, 0), (2 * far, 0, 0), (0, road, 0), asphalt, normal=(0, 0, 1))
    mesh.quad((-far, road / 2, 0), (2 * far, 0, 0), (0, far, 0), ground, normal=(0, 0, 1))
    mesh.quad((-far, -far, 0), (2 * far, 0, 0), (0, far - road / 2, 0), ground, normal=(0, 0, 1))
    placer = _Placer(mesh, rig)
    paving = materials.pick(rng, "pavement")
    for side in (-1, 1):
        placer.box(
            (0.0, side * (road / 2 + pavement / 2)),
            (2 * far, pavement, kerb),
            0.0,
            0.0,
            paving,
            exclusive=False,
        )
    extent = rng.uniform(80, 200)
    for side in (-1, 1):
        x = -extent
        while x < extent:
            width = rng.uniform(8, 30)
            height = float(np.exp(rng.uniform(np.log(5), np.log(40))))
            depth = rng.uniform(10, 25)
            setback = rng.uniform(0, 2) if rng.random() < 0.4 else 0.0
            cy = side * (front + setback + depth / 2)
            placer.box(
                (x + width / 2, cy),
                (width, depth, height),
                0.0,
                0.0,
                materials.pick(rng, "facade"),
                materials.pick(rng, "ground"),
                exclusive=False,
                facade_phase=True,
            )
            x += width + (rng.uniform(1, 8) if rng.random() < 0.3 else 0.0)
    if objects:
        _street_objects(rng, placer, materials, road, pavement, kerb)
    surfaces, windows = mesh.arrays()
    along = np.array([[-300.0, 0.0], [300.0, 0.0]])
    traffic = {
        "lanes": [(along + [0.0, -road / 4], 0.0), (along[::-1] + [0.0, road / 4], 0.0)],
        "walks": [(along + [0.0, side * (road / 2 + pavement / 2)], kerb) for side in (-1, 1)],
    }
    lighting, sky_yaw = _lighting_outdoor(rng), float(rng.random())
    return Scene("street", surfaces, windows, lighting, sky_yaw, 0.05, 8000.0, rig, traffic=traffic)


def _car(rng, placer: _Placer, materials, xy, yaw, z0=0.0) -> None:
    length, width = rng.uniform(3.8, 5.0), rng.uniform(1.6, 2.0)
    body = (length, width, rng.uniform(1.1, 1.5))
    if not placer.clear(xy, (length, width, body[2] + 0.25), z0, yaw) or not placer.free(xy, body):
        return
    paint = materials.pick(rng, "car", tile=(length, body[2]))
    placer.box(xy, body, z0 + 0.25, yaw, paint, materials.pick(rng, "pole"), exclusive=False)
    tyre = materials.pick(rng, "road")
    c, s = np.cos(yaw), np.sin(yaw)
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        lx, ly = sx * (length / 2 - 0.7), sy * (width / 2 - 0.15)
        placer.box(
            (xy[0] + c * lx - s * ly, xy[1] + s * lx + c * ly),
            (0.6, 0.25, 0.3),
            z0,
            yaw,
            tyre,
            exclusive=False,
        )
    placer.footprints.append((np.asarray(xy, dtype=float), 0.5 * float(np.hypot(length, width))))


def _street_objects(rng, placer: _Placer, materials, road, pavement, kerb) -> None:
    for _ in range(int(rng.integers(0, 10))):
        lane = rng.choice([-1, 1]) * rng.uniform(road / 8, road / 2 - 1.1)
        yaw = (0.0 if lane > 0 else np.pi) + rng.normal(0, 0.03)
        _car(rng, placer, materials, (rng.uniform(-60, 60), lane), yaw)
    pole = materials.pick(rng, "pole")
    spacing, x = rng.uniform(10, 25), rng.uniform(-80, -60)
    while x < 80:
        for side in (-1, 1):
            if rng.random() < 0.7:
                w = rng.uniform(0.1, 0.3)
                placer.box((x, side * (road / 2 + 0.5)), (w, w, rng.uniform(3, 9)), kerb, 0.0, pole)
        x += spacing
    for _ in range(int(rng.integers(0, 6))):  # bins, kiosks, planters
        size = (rng.uniform(0.4, 2.5), rng.uniform(0.4, 1.5), rng.uniform(0.5, 2.5))
        side = rng.choice([-1, 1])
        y = side * (road / 2 + rng.uniform(0.8, max(0.9, pavement - 0.8)))
        placer.box((rng.uniform(-50, 50), y), size, kerb, 0.0, materials.pick(rng, "object"))


def build_open(rng, rig_sample: RigSample, materials: MaterialIndex, objects: bool = True) -> Scene:
    """Open level ground to the horizon (plaza, car park, field) with scattered objects."""
    h = rng.uniform(0.4, 2.2) if rng.random() < 0.75 else rng.uniform(2.2, 8.0)
    if rig_sample.pitch > 0.8 * min(rig_sample.vfov_left, rig_sample.vfov_right) / 2:
        # open ground has nothing above the horizon but sky: look down instead of at an empty sky
        rig_sample = replace(rig_sample, pitch=-rig_sample.pitch)
    rig = rig_sample.place(np.array([0.0, 0.0, h]), float(rng.uniform(0, 2 * np.pi)))
    mesh = MeshBuilder()
    far = 3000.0
    mesh.quad(
        (-far, -far, 0),
        (2 * far, 0, 0),
        (0, 2 * far, 0),
        materials.pick(rng, rng.choice(["ground", "road", "pavement"])),
        normal=(0, 0, 1),
    )
    placer = _Placer(mesh, rig)
    if objects:
        for _ in range(int(rng.integers(15, 45))):
            r, a = float(np.exp(rng.uniform(np.log(3), np.log(80)))), rng.uniform(0, 2 * np.pi)
            xy = (r * np.cos(a), r * np.sin(a))
            kind = rng.choice(["car", "container", "pole", "building"], p=[0.4, 0.2, 0.2, 0.2])
            yaw = float(rng.uniform(0, np.pi))
            if kind == "car":
                _car(rng, placer, materials, xy, yaw)
            elif kind == "container":
                placer.box(xy, (rng.choice([6.1, 12.2]), 2.44, 2.6), 0.0, yaw, materials.pick(rng, "pole"))
            elif kind == "pole":
                w = rng.uniform(0.1, 0.3)
                placer.box(xy, (w, w, rng.uniform(3, 9)), 0.0, 0.0, materials.pick(rng, "pole"))
            else:
                xy = (xy[0] * 3 + np.sign(xy[0]) * 20, xy[1] * 3 + np.sign(xy[1]) * 20)
                size = (
                    rng.uniform(10, 40),
                    rng.uniform(10, 30),
                    float(np.exp(rng.uniform(np.log(5), np.log(40)))),
                )
                placer.box(
                    xy,
                    size,
                    0.0,
                    yaw,
                    materials.pick(rng, "facade"),
                    materials.pick(rng, "ground"),
                    facade_phase=True,
                )
    surfaces, windows = mesh.arrays()
    return Scene("open", surfaces, windows, _lighting_outdoor(rng), float(rng.random()), 0.05, 8000.0, rig)


def build_scene(
    rng,
    rig_sample: RigSample,
    materials: MaterialIndex,
    kind: str,
    objects: bool = True,
    baseline_m=(0.05, 0.8),
) -> Scene:
    """A scene of the given kind (one of SCENE_KINDS) around a rig drawn by the rig sampler.

    baseline_m: the sampler's baseline range, within which close-range scenes draw their shorter baseline.
    """
    if kind == "room":
        return build_room(rng, rig_sample, materials, corridor=False, objects=objects)
    if kind == "corridor":
        return build_room(rng, rig_sample, materials, corridor=True, objects=objects)
    if kind == "desk":
        return build_desk(rng, rig_sample, materials, objects=objects, baseline_m=baseline_m)
    if kind == "street":
        return build_street(rng, rig_sample, materials, objects=objects)
    if kind == "open":
        return build_open(rng, rig_sample, materials, objects=objects)
    raise ValueError(f"unknown scene kind {kind!r}; expected one of {SCENE_KINDS}")
