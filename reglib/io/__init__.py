"""Files in and out: images (read safely, PNG out), dense flow (``.flo``, ``.npy``), point sets
(text, ``.npy``, PLY, PCD), and atomic writes. Each kind lives in its own module; every public
name is re-exported here (``reglib.io.read_image``, ``reglib.io.read_points``, ...)."""
from .files import write_bytes_atomic
from .flow import encode_flo, encode_npy, read_flo, read_flow, write_flo, write_flow
from .images import (
    ALLOWED_FORMATS,
    DEFAULT_MAX_PIXELS,
    check_image_header,
    encode_png,
    image_format,
    image_size,
    read_image,
    to_uint8,
)
from .points import POINT_SUFFIXES, PointCloud, read_matches, read_point_cloud, read_points, write_points

__all__ = [
    "ALLOWED_FORMATS", "DEFAULT_MAX_PIXELS", "POINT_SUFFIXES", "PointCloud", "check_image_header",
    "encode_flo", "encode_npy", "encode_png", "image_format", "image_size", "read_flo", "read_flow",
    "read_image", "read_matches", "read_point_cloud", "read_points", "to_uint8", "write_bytes_atomic",
    "write_flo", "write_flow", "write_points",
]
