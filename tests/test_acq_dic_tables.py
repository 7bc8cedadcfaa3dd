"""VIC-3D CSV exports and generic point tables (CSV / NPZ with a column map) -> DICPoints in metres. VIC-3D: small
steps written here, and a real export (tests/data/vic3d-export)."""

import numpy as np
import pytest

from _data import data_path
from acquisition.dic import DICImportError, parse_column_map, read_point_table, read_vic3d_csv
from vfmlab.cli import main

# Small steps with VIC-3D's columns: quoted header, image coordinates x, y (px), image displacements u, v (px), sigma
# (px; -1 = not correlated), reference position X, Y, Z (mm), displacement U, V, W (mm), strains. (A real export has
# more columns, in another order, and spaces in its header: test_vic3d_real_export.)
VIC_HEADER = '"x","y","u","v","sigma","X","Y","Z","U","V","W","exx","eyy","exy"'
REF = np.array([[-5.0, -2.5, 1.25], [0.0, -2.5, 1.0], [5.0, -2.5, 1.5]])  # mm


def _vic_step(disp_mm: np.ndarray, sigma: np.ndarray) -> str:
    rows = [VIC_HEADER]
    for i, ((X, Y, Z), (U, V, W), s) in enumerate(zip(REF, disp_mm, sigma)):
        rows.append(f"{812 + 40 * i},{1010},{U * 25:.4f},{V * 25:.4f},{s},{X},{Y},{Z},{U},{V},{W},0.001,-0.0005,0")
    return "\n".join(rows) + "\n"


@pytest.fixture
def vic_files(tmp_path):
    steps = [np.zeros((3, 3)), np.full((3, 3), 0.1), np.array([[0.2, 0, 0], [0.2, 0.01, 0], [0.2, 0, -0.02]])]
    sigmas = [np.array([0.01, 0.012, 0.02]), np.array([0.011, -1, 0.02]), np.array([0.01, 0.013, 0.021])]
    paths = []
    for k, (d, s) in enumerate(zip(steps, sigmas)):
        p = tmp_path / f"spec_{k:04d}_0.csv"
        p.write_text(_vic_step(d, s))
        paths.append(p)
    return paths, steps


def test_vic3d_positions_in_metres_and_missing_points(vic_files):
    paths, steps = vic_files
    res = read_vic3d_csv(paths)
    assert res.points.shape == (3, 3, 3) and res.quality.shape == (3, 3)
    expected = (REF[None] + np.stack(steps)) * 1e-3
    expected[1, 1] = np.nan  # sigma = -1 at step 1
    np.testing.assert_allclose(res.points, expected, rtol=0, atol=1e-12)
    assert np.isnan(res.quality[1, 1]) and res.quality[0, 0] == pytest.approx(0.01)
    assert res.step_names == tuple(p.name for p in paths)
    np.testing.assert_allclose(res.displacements()[2, 0], [0.2e-3, 0, 0], atol=1e-12)


def test_vic3d_bad_files(tmp_path, vic_files):
    paths, _ = vic_files
    no_z = tmp_path / "no_z.csv"
    no_z.write_text('"x","y","X","Y","sigma"\n1,2,3,4,0.01\n')
    with pytest.raises(DICImportError, match="no_z.csv: no column 'Z'"):
        read_vic3d_csv([no_z])
    short = tmp_path / "short.csv"
    short.write_text(VIC_HEADER + "\n1,2,3,4,0.01,5,6,7,0,0,0,0,0,0\n")
    with pytest.raises(DICImportError, match="short.csv: 1 points; the first step"):
        read_vic3d_csv([paths[0], short])
    garbled = tmp_path / "garbled.csv"
    garbled.write_text(VIC_HEADER + "\n1,2,abc\n")
    with pytest.raises(DICImportError, match="garbled.csv: every row"):
        read_vic3d_csv([garbled])
    with pytest.raises(DICImportError, match="unit must be one of"):
        read_vic3d_csv(paths, unit="inch")


REAL = ("vic3d-export/def_init_vic3d.csv", "vic3d-export/def_final_vic3d.csv")


def test_vic3d_real_export():
    """Two steps of a real VIC-3D export (every 16th row: 264 points, 59 not correlated), header as VIC-3D writes it:
    ``' "X",  "Y",  "Z",  "U", ...'``, 31 columns, rows ``-17.4253,16.2764,...``."""
    res = read_vic3d_csv([data_path(p) for p in REAL])
    assert res.points.shape == (2, 264, 3) and res.step_names == ("def_init_vic3d.csv", "def_final_vic3d.csv")
    missing = np.isnan(res.points).any(axis=2)
    assert missing.sum(axis=1).tolist() == [59, 59] and np.array_equal(missing[0], missing[1])  # sigma = -1
    np.testing.assert_array_equal(np.isnan(res.quality), missing)
    # the file's 16th row: X Y Z -17.4253 16.2764 -297.282 mm in both steps (the reference position), U V W
    # 0.000731875 0.00284753 0.00140777 mm, then 4.0753 -1.23297 -0.789928 mm; sigma 0.00242078, 0.00541662 px
    np.testing.assert_allclose(res.points[:, 15] * 1e3,
                               [[-17.4253 + 0.000731875, 16.2764 + 0.00284753, -297.282 + 0.00140777],
                                [-17.4253 + 4.0753, 16.2764 - 1.23297, -297.282 - 0.789928]], rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.quality[:, 15], [0.00242078, 0.00541662], rtol=1e-12)
    moved = np.linalg.norm(res.displacements()[1], axis=1)[~missing[1]] * 1e3
    assert 4.03 < moved.min() and moved.max() < 4.34  # mm: 4.035-4.331 between the two steps


def test_vic3d_real_export_on_the_command_line(tmp_path, capsys):
    loads = tmp_path / "loads.csv"
    loads.write_text("step,pressure_kPa,axial_force_N,stretch\n0,2,0.1,1\n1,3,0.2,1.01\n")
    out = tmp_path / "vic.h5"
    assert main(["import-dic", *(str(data_path(p)) for p in REAL), "--format", "vic3d", "--loads", str(loads),
                 "--thickness-mm", "1.0", "-o", str(out)]) == 0
    assert "Imported 264 markers × 2 steps" in capsys.readouterr().out


def test_vic3d_real_header_bad_row(tmp_path):
    header = data_path(REAL[0]).read_text().splitlines()[0]
    cut = tmp_path / "cut.csv"
    cut.write_text(header + "\n-17.4253,16.2764,-297.282\n")
    with pytest.raises(DICImportError, match=r"cut.csv: every row must hold 31 numbers") as exc:
        read_vic3d_csv([cut])
    assert "\n" not in str(exc.value)


def test_generic_csv_with_column_map(tmp_path):
    p = tmp_path / "points.csv"
    p.write_text("frame;point;X;Y;Z;cc\n"
                 "0;10;1.0;2.0;3.0;0.01\n0;11;4.0;5.0;6.0;0.02\n"
                 "1;11;4.5;5.0;6.0;0.03\n1;10;1.5;2.0;3.0;0.04\n"
                 "2;10;2.0;2.0;3.0;0.05\n")  # point 11 missing at frame 2
    res = read_point_table(p, "id=point,step=frame,x=X,y=Y,z=Z,quality=cc", unit="mm")
    assert res.points.shape == (3, 2, 3)
    np.testing.assert_allclose(res.points[1], [[1.5e-3, 2e-3, 3e-3], [4.5e-3, 5e-3, 6e-3]])
    assert np.isnan(res.points[2, 1]).all() and res.quality[1, 0] == pytest.approx(0.04)
    assert res.step_names == ("0", "1", "2")


def test_generic_npz_without_ids_in_metres(tmp_path):
    p = tmp_path / "points.npz"
    step = np.array([0, 0, 1, 1])
    x = np.array([0.1, 0.2, 0.11, 0.21])
    np.savez(p, t=step, px=x, py=np.zeros(4), pz=np.ones(4))
    res = read_point_table(p, "step=t,x=px,y=py,z=pz", unit="m")
    np.testing.assert_allclose(res.points[:, :, 0], [[0.1, 0.2], [0.11, 0.21]])


def test_column_map_errors(tmp_path):
    assert parse_column_map("x=X, y=Y, z=Z") == {"x": "X", "y": "Y", "z": "Z"}
    with pytest.raises(DICImportError, match="'z' is required"):
        parse_column_map("x=X,y=Y")
    with pytest.raises(DICImportError, match="ROLE=COLUMN"):
        parse_column_map("x=X,y=Y,z=Z,colour=C")
    p = tmp_path / "t.csv"
    p.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(DICImportError, match="t.csv: no column 'X' for x"):
        read_point_table(p, "x=X,y=b,z=c")
    p.write_text("id,x,y,z\n1,0,0,0\n1,1,1,1\n")
    with pytest.raises(DICImportError, match="t.csv: a point appears twice"):
        read_point_table(p, "id=id,x=x,y=y,z=z")
