"""Files in and out: images (read safely; PNG, TIFF, BMP out), dense flow (``.flo``, ``.npy``, and ITK
displacement fields ``.mha`` / ``.nrrd`` / ``.nii.gz`` for medical tools), point sets
(text, ``.npy``, PLY, PCD), large TIFFs read by region or at a working size, and atomic writes.
Each kind lives in its own module; every public name is re-exported here (``reglib.io.read_image``,
``reglib.io.read_points``, ...)."""
from ._displacement import DISPLACEMENT_SUFFIXES, displacement_suffix, encode_mha, encode_nifti, encode_nrrd
from ._files import write_bytes_atomic
from ._flow import FLOW_SUFFIXES, encode_flo, encode_flow, encode_npy, read_flo, read_flow, write_flo, write_flow
from ._images import (
    ALLOWED_FORMATS,
    DEFAULT_MAX_PIXELS,
    IMAGE_OUT_SUFFIXES,
    check_image_header,
    encode_image,
    encode_png,
    image_format,
    image_size,
    read_image,
    to_uint8,
)
from ._points import POINT_SUFFIXES, PointCloud, read_matches, read_point_cloud, read_points, write_points
from ._tiff_regions import TiffRegions
from ._tiled_tiff import write_tiled_tiff
from ._working import WorkingImage, is_large_tiff, is_tiff_file, read_working_image, tiff_shape
from ._write_points import write_point_cloud

__all__ = [
    "ALLOWED_FORMATS", "DEFAULT_MAX_PIXELS", "DISPLACEMENT_SUFFIXES", "FLOW_SUFFIXES", "IMAGE_OUT_SUFFIXES",
    "POINT_SUFFIXES", "PointCloud", "TiffRegions", "WorkingImage", "check_image_header", "displacement_suffix",
    "encode_flo", "encode_flow", "encode_image", "encode_mha",
    "encode_nifti", "encode_npy", "encode_nrrd", "encode_png", "image_format", "image_size", "is_large_tiff",
    "is_tiff_file", "read_flo", "read_flow",
    "read_image", "read_matches", "read_point_cloud", "read_points", "read_working_image", "tiff_shape", "to_uint8",
    "write_bytes_atomic", "write_flo", "write_flow", "write_point_cloud", "write_points", "write_tiled_tiff",
]
