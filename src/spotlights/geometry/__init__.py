"""Geometry layer: rig, normalisation, ray casting, encoding, sampling, I/O.

Knows nothing of learning (no torch). Main entry points::

    from spotlights.geometry import make_rig, load_mesh, encode_mesh, decode
    rig = make_rig(32, 64, angle=60)
    depths = encode_mesh(load_mesh("car.ply"), rig)      # (2048,) float32, 0 = miss
    points, mask = decode(depths, rig)                   # (2048, 3) unit frame + hit mask
"""

from .box_json import box_from_dict, load_box
from .boxes import Box
from .encode import (
    Encoding,
    MeshProbe,
    decode,
    encode_mesh,
    encode_mesh_files,
    encode_meshes,
    hit_ratio,
    load_encoding,
    save_encoding,
)
from .frames import (
    Normalization,
    normalization_from_box,
    normalization_from_mesh,
    normalization_from_points,
)
from .io import load_mesh, load_points, save_points
from .raycast import RayCaster, first_hit
from .rig import Rig, RigSpec, cap_directions, fibonacci_sphere, make_rig, make_rig_spec
from .rotations import orthonormalize, quaternion_to_matrix, rotation_z
from .sampling import farthest_point_sample, resample, sample_surface

__all__ = [
    "Box",
    "box_from_dict",
    "load_box",
    "orthonormalize",
    "quaternion_to_matrix",
    "rotation_z",
    "Encoding",
    "MeshProbe",
    "Normalization",
    "RayCaster",
    "Rig",
    "RigSpec",
    "cap_directions",
    "decode",
    "encode_mesh",
    "encode_mesh_files",
    "encode_meshes",
    "farthest_point_sample",
    "fibonacci_sphere",
    "first_hit",
    "hit_ratio",
    "load_encoding",
    "load_mesh",
    "load_points",
    "make_rig",
    "make_rig_spec",
    "normalization_from_box",
    "normalization_from_mesh",
    "normalization_from_points",
    "resample",
    "sample_surface",
    "save_encoding",
    "save_points",
]
