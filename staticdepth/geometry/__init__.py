"""Pure geometry (numpy only, no I/O): cameras, rigs, mountings, projections, planes."""
from staticdepth.geometry.camera import (Camera, Mounting, StereoRig, load_camera,  # noqa: F401
                                         normal_from_pitch_roll, pitch_roll_from_normal)
from staticdepth.geometry.plane import (angle_between_deg, fit_plane, horizon_line,  # noqa: F401
                                        normalize_plane, plane_depth_at_pixels, plane_depth_map,
                                        point_plane_distance)
from staticdepth.geometry.projection import (depth_from_disparity, disparity_from_depth,  # noqa: F401
                                             pixel_grid, points_from_depth, project_points,
                                             ray_grid, rays_from_pixels, transform_points)
