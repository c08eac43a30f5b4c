"""What a sequence's ``report.html`` draws beyond its JSON report: the left camera's track through the
output world and each frame's reprojection error in the adjusted model, read from the
:class:`~stereogeo_cli.sequence.run.SequenceResult` that is written (its trajectory and its COLMAP model)."""

from __future__ import annotations

import numpy as np

from stereogeo_cli.report.inputs import ReportInputs, SequenceTrack


def frame_reprojection_px(reconstruction) -> dict[int, float]:
    """Per frame index the mean distance (pixels) between each observation of its two images and its 3-D
    point projected by the adjusted cameras (the images are named ``left/000012.png``, ``right/...``)."""
    errors: dict[int, list[np.ndarray]] = {}
    for image in reconstruction.images.values():
        if not image.has_pose:
            continue
        seen = [p for p in image.points2D if p.has_point3D()]
        if not seen:
            continue
        xyz = np.array([reconstruction.points3D[p.point3D_id].xyz for p in seen])
        observed = np.array([p.xy for p in seen])
        pose = np.asarray(image.cam_from_world().matrix())
        projected = np.asarray(image.camera.img_from_cam(xyz @ pose[:, :3].T + pose[:, 3]))
        try:
            index = int(image.name.split("/", 1)[1].split(".", 1)[0])
        except (IndexError, ValueError):
            continue
        errors.setdefault(index, []).append(np.linalg.norm(projected[:, :2] - observed, axis=1))
    return {index: float(np.mean(np.concatenate(parts))) for index, parts in sorted(errors.items())}


def sequence_inputs(result) -> ReportInputs:
    """The report's data of a sequence: its track (where COLMAP made a model; else none)."""
    if result.reconstruction is None or len(result.trajectory) < 2:
        return ReportInputs()
    poses = np.array([world_from_cam for _, world_from_cam in result.trajectory])
    track = SequenceTrack(
        positions=poses[:, :3, 3],
        axes=poses[:, :3, 2],
        reprojection_px=frame_reprojection_px(result.reconstruction),
    )
    return ReportInputs(track=track)
