"""Roads and traffic: the scene a car's rig drives through (``drive`` sequences), and cars and people that
move on their own between the frames of a sequence.

World: x east, y north, z up, metres (:mod:`stereogeo_cli.synth.scenes`). The road of a drive follows the
drive's own path (straight stretches and a gentle curve), with the camera on the right-hand lane: two lanes
with dashed centre and solid edge lines, parking strips with parked cars, kerbed pavements with trees
and poles, and building blocks of 5–25 m along both sides. The open ground beyond lies ``GROUND_DROP_M``
below the road (front gardens, verges), so its plane never fights with the road's in the depth buffer.

A :class:`Mover` is a car or a person following a path at a constant speed (back and forth along it when it
reaches an end); :func:`place_movers` draws them on the scene's lanes and pavements where it has them
(streets, roads) and on free straight paths elsewhere, always clear of the cameras at every time of the
sequence and of the scene's surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereogeo_cli.synth.rigs import RigSample
from stereogeo_cli.synth.scenes import (
    MaterialIndex,
    MaterialRef,
    MeshBuilder,
    Scene,
    _car,
    _lighting_outdoor,
    _Placer,
)

ROAD_CAMERA_HEIGHT_M = 1.6  # the left camera above the road, as on a car's roof rack (KITTI: 1.65 m)
GROUND_DROP_M = 0.3
ROAD_BEFORE_M, ROAD_AFTER_M = 60.0, 400.0  # the road runs on straight beyond the drive's two ends
ROAD_STEP_M = 4.0  # the road and its pavements are built of pieces this long
INDOOR_KINDS = ("room", "corridor", "desk")


# --- paths ------------------------------------------------------------------------------------------------


def _arc(path: np.ndarray) -> np.ndarray:
    """Arc length [P] along a polyline [P x 2], metres from its first point."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])


def along(path: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points [N x 2] and unit tangents [N x 2] at arc lengths ``s`` [N] of a polyline [P x 2]."""
    arc = _arc(path)
    s = np.clip(np.asarray(s, dtype=float), 0.0, arc[-1])
    points = np.stack([np.interp(s, arc, path[:, 0]), np.interp(s, arc, path[:, 1])], 1)
    k = np.clip(np.searchsorted(arc, s, side="right") - 1, 0, len(path) - 2)
    d = path[k + 1] - path[k]
    return points, d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def _extended(track: np.ndarray, before: float, after: float, step: float) -> np.ndarray:
    """The polyline [P x 2] continued straight ``before`` metres behind its start and ``after`` beyond its
    end, resampled every ``step`` metres or less."""
    first = track[1] - track[0] if len(track) > 1 else np.array([1.0, 0.0])
    last = track[-1] - track[-2] if len(track) > 1 else np.array([1.0, 0.0])
    first, last = (v / max(np.linalg.norm(v), 1e-12) for v in (first, last))
    full = np.vstack([track[0] - before * first, track, track[-1] + after * last])
    arc = _arc(full)
    s = np.linspace(0.0, arc[-1], int(np.ceil(arc[-1] / step)) + 1)
    return np.stack([np.interp(s, arc, full[:, 0]), np.interp(s, arc, full[:, 1])], 1)


def _left_normals(path: np.ndarray) -> np.ndarray:
    """Unit normals [P x 2] pointing to the left of the direction of travel (tangents of each point's
    segment forward; the last point takes the last segment's)."""
    d = np.diff(path, axis=0)
    d = np.vstack([d, d[-1:]]) / np.maximum(
        np.linalg.norm(np.vstack([d, d[-1:]]), axis=1, keepdims=True), 1e-12
    )
    return np.stack([-d[:, 1], d[:, 0]], 1)


# --- the road of a drive ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Section:
    """The road's cross-section: lateral offsets from the centre line, positive to the left, metres."""

    lane: float  # width of one lane
    right: float  # from the centre line to the right kerb
    left: float  # to the left kerb
    parking: tuple[bool, bool]  # a parking strip on the (right, left)
    strip: float  # width of a parking strip
    pavement: tuple[float, float]  # widths of the (right, left) pavements
    kerb: float  # height of the pavements above the road


def _section(rng) -> _Section:
    lane, strip = float(rng.uniform(3.2, 3.8)), float(rng.uniform(2.0, 2.4))
    parking = (bool(rng.random() < 0.6), bool(rng.random() < 0.5))
    right, left = (lane + strip * p + 0.3 for p in parking)
    pavement = (float(rng.uniform(2.0, 4.5)), float(rng.uniform(2.0, 4.5)))
    return _Section(lane, right, left, parking, strip, pavement, float(rng.uniform(0.1, 0.16)))


def _road_surface(mesh: MeshBuilder, centre: np.ndarray, sec: _Section, asphalt, marking, paving) -> None:
    """Asphalt, lane markings and the pavements (boxes from the sunken ground up to the kerb), piece by
    piece along the centre line [P x 2]; each piece overlaps the next by a few centimetres."""
    arc, normals = _arc(centre), _left_normals(centre)
    for i in range(len(centre) - 1):
        p, d, n = centre[i], centre[i + 1] - centre[i], normals[i]
        length = float(np.linalg.norm(d))
        t = d / max(length, 1e-12)
        across = sec.right + sec.left + 0.6
        p0 = np.array([*(p - n * (sec.right + 0.3) - 0.03 * t), 0.0])
        e_u = np.array([*(d + 0.06 * t), 0.0])
        mesh.quad(p0, e_u, (*(n * across), 0.0), asphalt, (arc[i] / asphalt.tile[0], 0.0), normal=(0, 0, 1))
        lines = [-sec.lane, sec.lane]  # solid lines at the lanes' outer edges
        if i % 3 == 0:  # the dashed centre line: one piece of line, two of gap
            lines.append(0.0)
        for offset in lines:
            start = np.array([*(p + n * (offset - 0.06)), 0.01])
            mesh.quad(start, (*d, 0.0), (*(n * 0.12), 0.0), marking, normal=(0, 0, 1))
        yaw = float(np.arctan2(t[1], t[0]))
        for side, edge, width in ((-1, sec.right, sec.pavement[0]), (1, sec.left, sec.pavement[1])):
            middle = p + d / 2 + side * n * (edge + width / 2 + 3.0)
            size = (length + 0.06, width + 6.0, sec.kerb + GROUND_DROP_M)
            mesh.box(middle, size, -GROUND_DROP_M, yaw, paving)


def _roadside(rng, placer: _Placer, materials: MaterialIndex, centre: np.ndarray, sec: _Section) -> None:
    """Building blocks along both sides, trees and poles on the pavements, cars in the parking strips."""
    total = _arc(centre)[-1]
    pole, leaves = materials.pick(rng, "pole"), materials.pick(rng, "ground")
    crown = MaterialRef(leaves.layer, (0.55, 0.8, 0.4), leaves.tile, leaves.mirror)
    for side, edge, width, parking in (
        (-1, sec.right, sec.pavement[0], sec.parking[0]), (1, sec.left, sec.pavement[1], sec.parking[1]),
    ):  # fmt: skip
        s = ROAD_BEFORE_M - 40.0
        while s < total - 20.0:
            front, depth = float(rng.uniform(8, 30)), float(rng.uniform(8, 20))
            height = float(np.exp(rng.uniform(np.log(5), np.log(25))))
            setback = float(rng.uniform(0.0, 4.0)) if rng.random() < 0.5 else 0.0
            (xy,), (t,) = along(centre, [s + front / 2])
            n = np.array([-t[1], t[0]])
            at = xy + side * n * (edge + width + setback + depth / 2)
            yaw = float(np.arctan2(t[1], t[0]))
            facade, roof = materials.pick(rng, "facade"), materials.pick(rng, "ground")
            size = (front, depth, height + GROUND_DROP_M)
            placer.box(at, size, -GROUND_DROP_M, yaw, facade, roof, exclusive=False, facade_phase=True)
            s += front + (float(rng.uniform(2, 10)) if rng.random() < 0.3 else 0.0)
        s = float(rng.uniform(0, 10))
        while s < total:
            (xy,), (t,) = along(centre, [s])
            n, yaw = np.array([-t[1], t[0]]), float(np.arctan2(t[1], t[0]))
            if rng.random() < 0.5:  # a tree: trunk and crown
                foot = xy + side * n * (edge + 0.7 * width)
                placer.box(foot, (0.25, 0.25, 2.6), sec.kerb, yaw, pole, exclusive=False)
                size = tuple(float(v) for v in rng.uniform([1.8, 1.8, 1.5], [3.0, 3.0, 2.8]))
                placer.box(foot, size, sec.kerb + 2.4, yaw, crown, exclusive=False)
            elif rng.random() < 0.4:  # a street-light pole at the kerb
                w = float(rng.uniform(0.12, 0.25))
                placer.box(xy + side * n * (edge + 0.4), (w, w, rng.uniform(4, 8)), sec.kerb, yaw, pole)
            if parking and rng.random() < 0.6:  # parked cars face the traffic of their side
                spot = xy + side * n * (sec.lane + sec.strip / 2)
                _car(rng, placer, materials, spot, yaw + (np.pi if side > 0 else 0.0))
            s += float(rng.uniform(6.0, 12.0))


def build_road(
    rng, rig_sample: RigSample, materials: MaterialIndex, track: np.ndarray, objects=True
) -> Scene:
    """The road a ``drive`` sequence drives along. The rig stands with its left camera at (0, 0,
    ROAD_CAMERA_HEIGHT_M) looking east (yaw 0); ``track`` [P x 2] is the left camera's path in that rig's
    heading frame (x right, y forward, metres; :class:`stereogeo_cli.synth.sequence.Motion`), and the rig's
    middle drives on the centre of the right-hand lane all along it."""
    rig = rig_sample.place(np.array([0.0, 0.0, ROAD_CAMERA_HEIGHT_M]), 0.0)
    sec = _section(rng)
    world = np.stack([track[:, 1], -track[:, 0]], 1)  # heading frame → world at yaw 0: forward is east
    path = _extended(world, ROAD_BEFORE_M, ROAD_AFTER_M, ROAD_STEP_M)
    half_rig = float((rig.right.center - rig.left.center)[1] / 2)  # < 0: the right camera is to the south
    left_camera = -sec.lane / 2 - half_rig  # the left camera's offset from the centre line
    normals = _left_normals(path)
    centre = path - normals * left_camera
    mesh = MeshBuilder()
    far, middle = 3000.0, centre[len(centre) // 2]
    ground = materials.pick(rng, "ground")
    mesh.quad((*(middle - far), -GROUND_DROP_M), (2 * far, 0, 0), (0, 2 * far, 0), ground, normal=(0, 0, 1))
    asphalt, paving, paint = (
        materials.pick(rng, "road"),
        materials.pick(rng, "pavement"),
        materials.pick(rng, "pole"),
    )
    marking = MaterialRef(paint.layer, (1.9, 1.9, 1.85), paint.tile, paint.mirror)
    _road_surface(mesh, centre, sec, asphalt, marking, paving)
    placer = _Placer(mesh, rig)
    if objects:
        _roadside(rng, placer, materials, centre, sec)
    surfaces, windows = mesh.arrays()
    n = _left_normals(centre)
    traffic = {
        "lanes": [(centre - n * sec.lane / 2, 0.0), ((centre + n * sec.lane / 2)[::-1], 0.0)],
        "walks": [
            (centre - n * (sec.right + 0.4 * sec.pavement[0]), sec.kerb),
            ((centre + n * (sec.left + 0.4 * sec.pavement[1]))[::-1], sec.kerb),
        ],
    }
    lighting, sky_yaw = _lighting_outdoor(rng), float(rng.random())
    return Scene("road", surfaces, windows, lighting, sky_yaw, 0.05, 8000.0, rig, traffic=traffic)


# --- things that move -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Mover:
    """A car or a person following ``path`` at ``speed``, back and forth between its ends.

    ``vertices`` [V x 13] (scenes.py's vertex layout) are in the object's own frame: x forward, y left,
    z up, origin at the middle of its footprint on the ground; ``z0`` is the ground's height there.
    """

    kind: str  # "car" or "person"
    vertices: np.ndarray
    path: np.ndarray  # [P x 2] world xy, in the direction it sets off
    z0: float
    start_m: float  # arc length along the path at t = 0
    speed: float  # m/s
    size: tuple[float, float, float]  # length, width, height, metres

    @property
    def radius(self) -> float:
        return 0.5 * float(np.hypot(self.size[0], self.size[1]))

    def pose(self, t) -> tuple[np.ndarray, np.ndarray]:
        """(xy [N x 2] world, yaw [N] radians of its x axis) at times ``t`` [N] seconds."""
        total = float(_arc(self.path)[-1])
        s = np.mod(self.start_m + self.speed * np.atleast_1d(np.asarray(t, dtype=float)), 2 * total)
        back = s > total
        xy, tangent = along(self.path, np.where(back, 2 * total - s, s))
        return xy, np.arctan2(tangent[:, 1], tangent[:, 0]) + np.pi * back

    def surfaces(self, t: float) -> np.ndarray:
        """Its vertices [V x 13] in world coordinates at time ``t``."""
        (xy,), (yaw,) = self.pose([t])
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        v = self.vertices.astype(np.float64)
        out = v.copy()
        out[:, 0:3] = v[:, 0:3] @ R.T + np.array([xy[0], xy[1], self.z0])
        out[:, 3:6] = v[:, 3:6] @ R.T
        return out.astype(np.float32)


def _car_mesh(rng, materials: MaterialIndex) -> tuple[np.ndarray, tuple]:
    length, width, height = (
        float(rng.uniform(3.8, 4.9)),
        float(rng.uniform(1.65, 1.95)),
        float(rng.uniform(1.35, 1.6)),
    )
    paint, glass, tyre = (
        materials.pick(rng, "car", tile=(length, 1.0)),
        materials.pick(rng, "pole"),
        materials.pick(rng, "road"),
    )
    mesh = MeshBuilder()
    mesh.box((0.0, 0.0), (length, width, 0.7), 0.3, 0.0, paint)
    mesh.box((-0.08 * length, 0.0), (0.55 * length, 0.92 * width, height - 1.0), 1.0, 0.0, glass, paint)
    for sx in (-1, 1):
        for sy in (-1, 1):
            mesh.box((sx * (length / 2 - 0.75), sy * (width / 2 - 0.12)), (0.62, 0.26, 0.62), 0.0, 0.0, tyre)
    return mesh.arrays()[0], (length, width, height)


def _person_mesh(rng, materials: MaterialIndex) -> tuple[np.ndarray, tuple]:
    height = float(rng.uniform(1.55, 1.9))
    legs, top = materials.pick(rng, "object"), materials.pick(rng, rng.choice(["object", "car"]))
    skin = MaterialRef(top.layer, (0.95, 0.75, 0.6), (0.3, 0.3), top.mirror)
    mesh = MeshBuilder()
    mesh.box((0.0, 0.0), (0.28, 0.4, 0.48 * height), 0.0, 0.0, legs)
    mesh.box((0.0, 0.0), (0.3, 0.46, 0.37 * height), 0.48 * height, 0.0, top)
    mesh.box((0.0, 0.0), (0.22, 0.2, 0.15 * height), 0.85 * height, 0.0, skin)
    return mesh.arrays()[0], (0.3, 0.46, height)


def _candidate(rng, scene: Scene, materials, track: _Track) -> Mover | None:
    """One mover that passes through the view around a random time: on a lane or a pavement of the scene
    where it has them, else on a straight path ahead of the cameras (indoors: a person, inside the room)."""
    k = int(rng.integers(len(track.times)))
    t_c, centre, forward = track.times[k], track.middle[k], track.forward[k]
    indoor = scene.kind in INDOOR_KINDS
    car = not indoor and rng.random() < 0.55
    vertices, size = _car_mesh(rng, materials) if car else _person_mesh(rng, materials)
    kind = "car" if car else "person"
    speed = float(rng.uniform(5.0, 13.0) if car else rng.uniform(0.9, 1.7))
    heading = forward[:2] / max(np.linalg.norm(forward[:2]), 1e-9)
    ahead = rng.uniform(6.0, 40.0) if car else rng.uniform(1.5, 4.0) if indoor else rng.uniform(4.0, 25.0)
    target = centre[:2] + heading * float(ahead)
    if scene.traffic and rng.random() < 0.9:
        path, z0 = scene.traffic["lanes" if car else "walks"][int(rng.integers(2))]
        s_near = _arc(path)[int(np.argmin(np.linalg.norm(path - target, axis=1)))]
        return Mover(kind, vertices, path, float(z0), float(s_near - speed * t_c), speed, size)
    a = float(rng.uniform(0, 2 * np.pi))
    direction = np.array([np.cos(a), np.sin(a)])
    half = speed * float(track.times[-1] - track.times[0]) / 2 + 2.0
    ends = np.array([target - direction * half, target + direction * half])
    if indoor:  # keep the walk inside the room's floor
        xy = scene.surfaces[:, :2]
        ends = np.clip(ends, xy.min(axis=0) + 0.4, xy.max(axis=0) - 0.4)
        if np.linalg.norm(ends[1] - ends[0]) < 1.0:
            return None
    s0 = float(np.linalg.norm(target - ends[0])) - speed * t_c
    return Mover(kind, vertices, ends, 0.0, s0, speed, size)


def _axis(mover: Mover, xy: np.ndarray, yaw: np.ndarray, f: float) -> np.ndarray:
    """Points [N x 2] on the long axis of a mover's footprint: f = -1 rear, 0 middle, 1 front (the axis
    ends half a width short of the ends, so the footprint is the axis widened by half its width)."""
    reach = max(mover.size[0] - mover.size[1], 0.0) / 2
    return xy + f * reach * np.stack([np.cos(yaw), np.sin(yaw)], 1)


def _to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances [N] of points p [N x 2] to the segments a–b [N x 2]."""
    ab = b - a
    t = np.clip(np.einsum("nk,nk->n", p - a, ab) / np.maximum(np.einsum("nk,nk->n", ab, ab), 1e-12), 0, 1)
    return np.linalg.norm(p - a - t[:, None] * ab, axis=1)


def _keeps_clear(mover: Mover, track: _Track, distance_to_static, others, margin: float) -> bool:
    """Whether ``mover``'s footprint keeps ``margin`` metres from both cameras at every time, 0.3 m from
    the other movers', and its body clear of the scene's surfaces."""
    xy, yaw = mover.pose(track.times)
    rear, front = _axis(mover, xy, yaw, -1.0), _axis(mover, xy, yaw, 1.0)
    half = mover.size[1] / 2
    for side in range(2):
        if np.any(_to_segment(track.cameras[:, side, :2], rear, front) - half < margin):
            return False
    for other in others:
        oxy, oyaw = other.pose(track.times)
        for f in np.linspace(-1.0, 1.0, 5):
            if np.any(_to_segment(_axis(other, oxy, oyaw, f), rear, front) - half - other.size[1] / 2 < 0.3):
                return False
    width, height = mover.size[1], mover.size[2]
    k = np.linspace(0, len(track.times) - 1, 12).round().astype(int)
    points = np.concatenate([_axis(mover, xy[k], yaw[k], f) for f in (-1.0, 0.0, 1.0)])
    points = np.column_stack([points, np.full(len(points), mover.z0 + height / 2)])
    return bool(np.all(distance_to_static(points) >= 0.9 * min(width, height) / 2))


class _Track:
    """The rig at ``times`` [N] (seconds): ``cameras`` [N x 2 x 3] both camera centres, ``middle`` [N x 3]
    the rig's middle and ``forward`` [N x 3] the left camera's optical axis, in world coordinates."""

    def __init__(self, rigs_at, times: np.ndarray):
        rigs = rigs_at(times)
        self.times = times
        self.cameras = np.array([[r.left.center, r.right.center] for r in rigs])
        self.middle = self.cameras.mean(axis=1)
        self.forward = np.array([r.left.R_wc[2] for r in rigs])


def place_movers(rng, scene: Scene, materials: MaterialIndex, count: int, times, rigs_at, distance_to_static):
    """``count`` movers for ``scene`` (fewer where no more fit after 30 tries each), as a tuple.

    times: [N] the sequence's frame times, seconds; rigs_at(times) → the rig (stereogeo_cli.synth.rigs.Rig)
    at each; distance_to_static(points [M x 3]) → [M] metres to the nearest surface of the scene."""
    times = np.asarray(times, dtype=float)
    track = _Track(rigs_at, np.linspace(times.min() - 0.1, times.max() + 0.1, 200))
    margin = 0.6 if scene.kind in INDOOR_KINDS else 1.5
    movers: list[Mover] = []
    for _ in range(30 * count):
        if len(movers) == count:
            break
        mover = _candidate(rng, scene, materials, track)
        if mover is not None and _keeps_clear(mover, track, distance_to_static, movers, margin):
            movers.append(mover)
    return tuple(movers)
