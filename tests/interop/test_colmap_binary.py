"""COLMAP binary models: the same Block as the text reader on pycolmap's write_text of the same model; bad files."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lidarcat.errors import FormatError
from lidarcat.interop.colmap import read_colmap
from lidarcat.interop.colmap_binary import read_colmap_binary, read_colmap_rigs_binary
from lidarcat.interop.rotations import quaternion_wxyz_to_matrix

pycolmap = pytest.importorskip("pycolmap")


def _model(tmp_path, model="OPENCV", params=(1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4), rigs=2):
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_frames_per_rig, o.num_points3D = rigs, 3, 40
    o.camera_model_id = getattr(pycolmap.CameraModelId, model)
    o.camera_params = list(params)
    rec = pycolmap.synthesize_dataset(o)
    (tmp_path / "bin").mkdir()
    (tmp_path / "txt").mkdir()
    rec.write_binary(str(tmp_path / "bin"))
    rec.write_text(str(tmp_path / "txt"))
    return tmp_path / "bin", tmp_path / "txt", rec


def _same(a, b):
    for f in ("photo_ids", "photo_camera", "obs_photo", "obs_point", "point_ids"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    for f in ("eo", "obs_px", "obs_mm", "points_m"):
        # the text files carry 17 significant digits: the same doubles
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    assert a.cameras.keys() == b.cameras.keys()
    for c in a.cameras:
        da, db = a.cameras[c].to_dict(), b.cameras[c].to_dict()
        assert da.pop("source").split(": ", 1)[1] == db.pop("source").split(": ", 1)[1]
        assert da == db
    assert a.source_models == b.source_models


@pytest.mark.parametrize("model,params", [
    ("OPENCV", (1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4)),
    ("SIMPLE_RADIAL", (1280.0, 512.0, 384.0, 0.05)),
    ("FULL_OPENCV", (1280.0, 1270.0, 512.0, 384.0, 0.05, -0.01, 1e-3, -5e-4, 0.002, 0.01, 0.0, 0.0)),
])
def test_binary_and_text_models_give_the_same_block(tmp_path, model, params):
    b, t, rec = _model(tmp_path, model, params)
    blk = read_colmap_binary(b, name="m")
    _same(blk, read_colmap(t, name="m"))
    assert len(blk.photo_ids) == rec.num_images() == 6 and len(blk.cameras) == 2
    assert len(blk.obs_point) == rec.compute_num_observations()
    assert blk.description.startswith("imported from the COLMAP binary model")


def test_missing_and_truncated_files(tmp_path):
    b, _, _ = _model(tmp_path)
    data = (b / "images.bin").read_bytes()
    (b / "images.bin").write_bytes(data[:100])
    with pytest.raises(FormatError, match=re.escape(f"{b / 'images.bin'}: byte 0: field 'num_images': 6 items "
                                                    "cannot fit in the 92 bytes left (truncated or not a COLMAP "
                                                    "binary file)")):
        read_colmap_binary(b)
    (b / "images.bin").write_bytes(data[:1000])
    with pytest.raises(FormatError, match=r"images\.bin: byte \d+: field '(NUM_POINTS2D|X|IMAGE_ID|QW|NAME)': "):
        read_colmap_binary(b)
    (b / "images.bin").write_bytes(data[:5])
    with pytest.raises(FormatError, match=re.escape(f"{b / 'images.bin'}: byte 0: field 'num_images': the file "
                                                    f"ends after 5 bytes (truncated)")):
        read_colmap_binary(b)
    (b / "images.bin").write_bytes(data + b"\0")
    with pytest.raises(FormatError, match=re.escape(f"{b / 'images.bin'}: byte {len(data)}: field 'end': 1 byte(s) "
                                                    f"after the last record")):
        read_colmap_binary(b)
    (b / "points3D.bin").unlink()
    with pytest.raises(FormatError, match=re.escape(f"{b / 'points3D.bin'}: file not found")):
        read_colmap_binary(b)


def test_unsupported_models_and_bad_values_are_refused(tmp_path):
    b, _, _ = _model(tmp_path, "OPENCV_FISHEYE", (500.0, 501.0, 512.0, 384.0, 0.02, -0.01, 0.003, -0.0005), rigs=1)
    data = bytearray((b / "cameras.bin").read_bytes())
    data[12] = 10                                  # THIN_PRISM_FISHEYE
    (b / "cameras.bin").write_bytes(bytes(data))
    with pytest.raises(FormatError, match=re.escape(f"{b / 'cameras.bin'}: byte 12: field 'MODEL_ID': camera 1: camera "
                                                    "model 'THIN_PRISM_FISHEYE' is not supported")):
        read_colmap_binary(b)
    data[12] = 4                                   # OPENCV
    data[32:40] = np.float64(np.nan).tobytes()      # fx
    (b / "cameras.bin").write_bytes(bytes(data))
    with pytest.raises(FormatError, match=re.escape(f"{b / 'cameras.bin'}: byte 32: field 'fx': nan is not a "
                                                    "finite number")):
        read_colmap_binary(b)


def _rigid(pose):
    return quaternion_wxyz_to_matrix(pose[:4]), np.asarray(pose[4:])


def test_rigs_and_frames_compose_to_the_image_poses(tmp_path):
    o = pycolmap.SyntheticDatasetOptions()
    o.num_rigs, o.num_cameras_per_rig, o.num_frames_per_rig, o.num_points3D = 2, 3, 2, 10
    rec = pycolmap.synthesize_dataset(o)
    rec.write_binary(str(tmp_path))
    rigs, frames = read_colmap_rigs_binary(tmp_path)
    assert sorted(rigs) == [1, 2] and len(frames) == 4
    assert all(len(r.sensors) == 2 and all(p is not None for p in r.sensors.values()) for r in rigs.values())
    for fr in frames.values():
        r_rig, t_rig = _rigid(fr.rig_from_world)
        assert len(fr.data) == 3
        for kind, sid, image_id in fr.data:
            assert kind == "CAMERA"
            img = rec.image(image_id)
            assert img.camera_id == sid and img.frame_id == fr.frame_id
            rig = rigs[fr.rig_id]
            r_s, t_s = (np.eye(3), np.zeros(3)) if (kind, sid) == rig.ref_sensor else _rigid(rig.sensors[(kind, sid)])
            want = img.cam_from_world().matrix()
            np.testing.assert_allclose(r_s @ r_rig, want[:, :3], atol=1e-12)
            np.testing.assert_allclose(r_s @ t_rig + t_s, want[:, 3], atol=1e-12)
    (tmp_path / "frames.bin").write_bytes((tmp_path / "frames.bin").read_bytes()[:-3])
    with pytest.raises(FormatError, match=re.escape(f"{tmp_path / 'frames.bin'}: byte ")):
        read_colmap_rigs_binary(tmp_path)
    (tmp_path / "rigs.bin").unlink()
    with pytest.raises(FormatError, match=re.escape(f"{tmp_path / 'rigs.bin'}: file not found (COLMAP writes "
                                                    "rigs.bin and frames.bin from version 3.12 on)")):
        read_colmap_rigs_binary(tmp_path)
