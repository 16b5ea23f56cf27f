"""KITTI calibration readers/writer on the real files in shared/data, plus bad-input messages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from core.errors import InputError
from pipeline.kitti.calib import (
    read_object_calib,
    read_odometry_calib,
    read_raw_cam_to_cam,
    read_raw_imu_to_velo,
    read_raw_velo_to_cam,
    write_odometry_calib,
)

TRANSCRIBED = "kitti_odometry_06_color/calib_odometry_seq04-12_TRANSCRIBED.txt"
GRAY = "kitti_odometry_06_gray/calib.txt"
OBJECT = "kitti_object_000008/calib_000008.txt"
RAW = "kitti_raw_calib_2011_09_26/2011_09_26_calib/2011_09_26"


def test_odometry_calib_transcribed_has_p0_to_p3_and_skips_comments(shared_data: Path):
    c = read_odometry_calib(shared_data / TRANSCRIBED)
    assert list(c.P) == ["P0", "P1", "P2", "P3"]
    assert c.Tr is None
    for M in c.P.values():
        assert M.shape == (3, 4) and M.dtype == np.float64
        assert M[0, 0] == 707.0912 and M[1, 1] == 707.0912
        assert M[0, 2] == 601.8873 and M[1, 2] == 183.1104
    assert c.P["P2"][0, 3] == 46.88783 and c.P["P2"][2, 3] == 6.203223e-03
    assert c.P["P3"][0, 3] == -333.4597


def test_odometry_calib_gray_two_line_form_is_p0_p1(shared_data: Path):
    c = read_odometry_calib(shared_data / GRAY)
    assert list(c.P) == ["P0", "P1"]
    ref = read_odometry_calib(shared_data / TRANSCRIBED)
    np.testing.assert_array_equal(c.P["P0"], ref.P["P0"])
    np.testing.assert_array_equal(c.P["P1"], ref.P["P1"])
    # stereo baseline bf / f = 379.8145 / 707.0912 (pyslam's KITTI04-12.yaml: bf = 379.8145)
    assert -c.P["P1"][0, 3] / c.P["P1"][0, 0] == pytest.approx(0.537151, abs=1e-6)


def test_write_odometry_calib_reproduces_kitti_text_exactly(shared_data: Path, tmp_path: Path):
    src = shared_data / TRANSCRIBED
    c = read_odometry_calib(src)
    out = tmp_path / "calib.txt"
    write_odometry_calib(out, c.P, None)
    original = [ln for ln in src.read_text().splitlines() if ln and not ln.startswith("#")]
    assert out.read_text().splitlines() == original


def test_write_then_read_odometry_calib_with_tr(shared_data: Path, tmp_path: Path):
    P = read_odometry_calib(shared_data / TRANSCRIBED).P
    Tr = read_object_calib(shared_data / OBJECT).velo_to_cam_rect()
    out = tmp_path / "sub" / "calib.txt"
    write_odometry_calib(out, {"P2": P["P2"], "P0": P["P0"]}, Tr)
    lines = out.read_text().splitlines()
    assert [ln.split(":")[0] for ln in lines] == ["P0", "P2", "Tr"]
    assert all(len(ln.split()) == 13 for ln in lines)
    back = read_odometry_calib(out)
    np.testing.assert_allclose(back.P["P2"], P["P2"], rtol=1e-12)
    np.testing.assert_allclose(back.Tr, Tr, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(back.Tr[3], [0, 0, 0, 1])


def test_object_calib_and_velo_to_cam_rect(shared_data: Path):
    c = read_object_calib(shared_data / OBJECT)
    assert sorted(c.P) == ["P0", "P1", "P2", "P3"]
    assert c.R0_rect.shape == (3, 3) and c.Tr_velo_to_cam.shape == (3, 4) and c.Tr_imu_to_velo.shape == (3, 4)
    P2_4x4 = np.loadtxt(shared_data / "kitti_object_000008/000008.txt").reshape(4, 4)
    np.testing.assert_array_equal(c.P["P2"], P2_4x4[:3])
    T = c.velo_to_cam_rect()
    assert T.shape == (4, 4)
    np.testing.assert_allclose(T[:3, :3], c.R0_rect @ c.Tr_velo_to_cam[:, :3], rtol=1e-12)
    np.testing.assert_allclose(T[:3, 3], c.R0_rect @ c.Tr_velo_to_cam[:, 3], rtol=1e-12)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    # velodyne x (forward) is camera z, velodyne y (left) is camera −x, velodyne z (up) is camera −y
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 0, 1], atol=0.02)
    np.testing.assert_allclose(T[:3, :3] @ [0, 1, 0], [-1, 0, 0], atol=0.02)
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [0, -1, 0], atol=0.02)


def test_raw_cam_to_cam(shared_data: Path):
    r = read_raw_cam_to_cam(shared_data / RAW / "calib_cam_to_cam.txt")
    assert r.cameras == ["00", "01", "02", "03"]
    P2 = r.P_rect["02"]
    assert (P2[0, 0], P2[0, 2], P2[1, 2]) == (721.5377, 609.5593, 172.854)
    np.testing.assert_array_equal(r.S_rect["02"], [1242, 375])
    np.testing.assert_array_equal(r.S["00"], [1392, 512])
    assert r.D["00"].shape == (5,) and r.D["00"][0] == -3.728755e-01
    assert r.K["02"].shape == (3, 3) and r.K["02"][0, 0] == 9.597910e02
    assert r.T["01"][0] == -5.37e-01
    assert r.R["01"].shape == r.R_rect["03"].shape == (3, 3)
    assert r.calib_time == "09-Jan-2012 13:57:47" and r.corner_dist == 9.95e-02


def test_raw_velo_and_imu_agree_with_the_object_calibration(shared_data: Path):
    """Object frame 000008 was recorded on 2011_09_26: its calib is the raw one at more digits."""
    r = read_raw_cam_to_cam(shared_data / RAW / "calib_cam_to_cam.txt")
    T_velo = read_raw_velo_to_cam(shared_data / RAW / "calib_velo_to_cam.txt")
    T_imu = read_raw_imu_to_velo(shared_data / RAW / "calib_imu_to_velo.txt")
    assert T_velo.shape == (4, 4)
    np.testing.assert_array_equal(T_velo[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(T_velo[:3, 3], [-4.069766e-03, -7.631618e-02, -2.717806e-01])
    obj = read_object_calib(shared_data / OBJECT)
    np.testing.assert_allclose(T_velo[:3], obj.Tr_velo_to_cam, atol=1e-6)
    np.testing.assert_allclose(T_imu[:3], obj.Tr_imu_to_velo, atol=1e-6)
    np.testing.assert_allclose(r.R_rect["00"], obj.R0_rect, atol=1e-6)
    np.testing.assert_allclose(r.velo_to_cam_rect(T_velo), obj.velo_to_cam_rect(), atol=1e-6)


def test_tracking_style_keys_are_accepted(shared_data: Path, tmp_path: Path):
    text = (shared_data / OBJECT).read_text()
    for new, old in [("R_rect", "R0_rect:"), ("Tr_velo_cam", "Tr_velo_to_cam:"), ("Tr_imu_velo", "Tr_imu_to_velo:")]:
        text = text.replace(old, new)
    f = tmp_path / "0000.txt"
    f.write_text(text)
    c = read_object_calib(f)
    np.testing.assert_array_equal(c.velo_to_cam_rect(), read_object_calib(shared_data / OBJECT).velo_to_cam_rect())


# ------------------------------------------------------------------ bad input


def _edited(src: Path, dst: Path, edit) -> Path:
    dst.write_text("\n".join(edit(ln) for ln in src.read_text().splitlines()) + "\n")
    return dst


def test_object_calib_missing_key_names_file_and_key(shared_data: Path, tmp_path: Path):
    f = _edited(shared_data / OBJECT, tmp_path / "c.txt", lambda ln: "" if ln.startswith("R0_rect") else ln)
    with pytest.raises(InputError) as e:
        read_object_calib(f)
    assert str(f) in str(e.value) and "'R0_rect'" in str(e.value)


def test_object_calib_wrong_count_names_key_and_count(shared_data: Path, tmp_path: Path):
    f = _edited(
        shared_data / OBJECT, tmp_path / "c.txt", lambda ln: ln.rsplit(" ", 1)[0] if ln.startswith("P2:") else ln
    )
    with pytest.raises(InputError) as e:
        read_object_calib(f)
    msg = str(e.value)
    assert str(f) in msg and "'P2'" in msg and "expected 12" in msg and "got 11" in msg


def test_odometry_calib_errors(shared_data: Path, tmp_path: Path):
    cases = {
        "short_p2": lambda ln: ln.rsplit(" ", 2)[0] if ln.startswith("P2:") else ln,
        "no_number": lambda ln: ln.replace("4.688783000000e+01", "4.68x") if ln.startswith("P2:") else ln,
        "dup": lambda ln: ln.replace("P3:", "P2:"),
        "tr_short": lambda ln: ln + "\nTr: 1 0 0 0 0 1 0 0 0 0 1" if ln.startswith("P3:") else ln,
        "nothing": lambda ln: "# only comments",
    }
    expect = {"short_p2": "'P2'", "no_number": "'4.68x'", "dup": "appears twice", "tr_short": "'Tr'", "nothing": "'P0'"}
    for name, edit in cases.items():
        f = _edited(shared_data / TRANSCRIBED, tmp_path / f"{name}.txt", edit)
        with pytest.raises(InputError) as e:
            read_odometry_calib(f)
        assert str(f) in str(e.value) and expect[name] in str(e.value), (name, str(e.value))


def test_missing_file_and_raw_missing_key(shared_data: Path, tmp_path: Path):
    with pytest.raises(InputError, match="file not found"):
        read_odometry_calib(tmp_path / "nope.txt")
    f = _edited(
        shared_data / RAW / "calib_cam_to_cam.txt", tmp_path / "cc.txt", lambda ln: "" if ln.startswith("K_02") else ln
    )
    with pytest.raises(InputError) as e:
        read_raw_cam_to_cam(f)
    assert str(f) in str(e.value) and "'K_02'" in str(e.value)
    g = _edited(
        shared_data / RAW / "calib_velo_to_cam.txt", tmp_path / "vc.txt", lambda ln: "" if ln.startswith("T:") else ln
    )
    with pytest.raises(InputError) as e:
        read_raw_velo_to_cam(g)
    assert str(g) in str(e.value) and "'T'" in str(e.value)
