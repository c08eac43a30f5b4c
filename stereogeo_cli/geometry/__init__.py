"""Geometry: the one home of the maths of gravity, cameras, perspective fields, rotations, epipoles."""

from stereogeo_cli.geometry.camera import (
    TURNS_DEG,
    ImageTurn,
    ResizeCrop,
    apply_resize_crop,
    corner_radius,
    division_limit,
    focal_from_vfov,
    fold_k3,
    intrinsic_matrix,
    opencv_from_division,
    principal_point,
    resize_crop_for_network,
    undistort_division,
    vfov_from_focal,
)
from stereogeo_cli.geometry.epipolar import (
    essential_matrix,
    fundamental_matrix,
    rectified_row_differences,
    symmetric_epipolar_distance,
)
from stereogeo_cli.geometry.fields import (
    fields_and_jacobians,
    latitude_at,
    latitude_field,
    pixel_grid,
    up_at,
    up_field,
)
from stereogeo_cli.geometry.gravity import (
    couple_rotation_to_gravity,
    gravity_angle,
    gravity_coupling_error,
    gravity_from_roll_pitch,
    retract_on_sphere,
    roll_pitch_from_gravity,
    tangent_basis,
)
from stereogeo_cli.geometry.rotation import (
    axis_angle_from_rotation,
    closest_rotation,
    quaternion_from_rotation,
    quaternion_to_rotation,
    rotation_angle,
    rotation_between_vectors,
    rotation_error,
    rotation_from_axis_angle,
    skew,
)

__all__ = [
    "TURNS_DEG", "ImageTurn", "ResizeCrop", "apply_resize_crop", "corner_radius", "division_limit",
    "focal_from_vfov", "fold_k3", "intrinsic_matrix", "opencv_from_division", "principal_point",
    "resize_crop_for_network", "undistort_division", "vfov_from_focal", "essential_matrix",
    "fundamental_matrix", "rectified_row_differences", "symmetric_epipolar_distance", "fields_and_jacobians",
    "latitude_at", "latitude_field", "pixel_grid", "up_at", "up_field", "couple_rotation_to_gravity",
    "gravity_angle", "gravity_coupling_error", "gravity_from_roll_pitch", "retract_on_sphere",
    "roll_pitch_from_gravity", "tangent_basis", "axis_angle_from_rotation", "closest_rotation",
    "quaternion_from_rotation", "quaternion_to_rotation", "rotation_angle", "rotation_between_vectors",
    "rotation_error", "rotation_from_axis_angle", "skew",
]  # fmt: skip
