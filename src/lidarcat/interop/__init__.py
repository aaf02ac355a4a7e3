"""Import and export of other photogrammetric programs' files (docs/formats/).

One module per format, all going through :class:`~lidarcat.interop.block.Block`
(cameras, orientations in lidarcat's convention, observations, points, control):

========================  ==================================================================
module                    reads / writes
========================  ==================================================================
:mod:`.colmap`            COLMAP text models (cameras.txt, images.txt, points3D.txt)
:mod:`.colmap_binary`     COLMAP binary models (cameras.bin, images.bin, points3D.bin), read
:mod:`.opensfm`           OpenSfM reconstruction.json, tracks.csv, ground_control_points.json
:mod:`.odm`               OpenDroneMap gcp_list.txt and geo.txt
:mod:`.metashape`         Metashape project XML (chunk + frame doc.xml)
:mod:`.opk`               omega-phi-kappa text (IGN .OPK, Pix4D layout), IGN Borea companions
:mod:`.gnss`              GNSS/IMU text (omega/phi/kappa or roll/pitch/yaw), kapture GNSS
:mod:`.gis`               GIS layer set of an adjusted block (GeoPackage or GeoJSON)
:mod:`.heights`           ellipsoidal / orthometric heights per source, geoid grids
:mod:`.rotations`         the rotation conventions and their conversions
:mod:`.lens`              every camera as the Brown (OpenCV) or fisheye model an export writes
:mod:`.cameras`           source cameras (Brown, fisheye): stand-in pinhole, ideal observations
:mod:`.rigs`              multi-camera rigs: COLMAP rigs.txt/frames.txt, OpenSfM rig entries
:mod:`.convert`           one format to another through the block, without adjusting
:mod:`.block`             the common block, survey-folder writer and reader
:mod:`.merge`             orientation and ground-control files merged into a copy of a survey
========================  ==================================================================

Errors are :class:`lidarcat.errors.FormatError` ``FILE:LINE: field 'NAME': ...``.
"""

from .block import (
                    Block,
                    GroundControl,
                    Orientations,
                    apply_ground_control,
                    apply_orientations,
                    block_from_survey,
                    reprojection_residuals_mm,
                    reprojection_residuals_px,
                    write_survey,
)
from .colmap import read_colmap, write_colmap
from .gis import gis_layers, write_gis
from .gnss import read_gnss, read_kapture_gnss
from .heights import HeightError, convert_heights, harmonise_ground_points, write_harmonised_survey
from .metashape import read_metashape
from .odm import read_gcp_list, read_geo_txt
from .opensfm import read_opensfm, read_opensfm_gcp, write_opensfm
from .opk import read_borea, read_opk, write_opk

__all__ = [
    "Block", "GroundControl", "Orientations", "apply_ground_control", "apply_orientations",
    "block_from_survey", "reprojection_residuals_mm", "reprojection_residuals_px", "write_survey",
    "read_colmap", "write_colmap", "read_opensfm", "read_opensfm_gcp", "write_opensfm",
    "read_gcp_list", "read_geo_txt", "read_metashape", "read_opk", "write_opk", "read_borea",
    "read_gnss", "read_kapture_gnss", "gis_layers", "write_gis", "HeightError", "convert_heights",
    "harmonise_ground_points", "write_harmonised_survey",
]
