"""ParaView export: legacy VTK polydata parsed back, PLY read back with trimesh."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from rig_sim.synthetic_session import make_session
from acquisition.session import open_session
from vfmlab.cli import main
from vfmlab.fields import compute_fields


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return make_session(tmp_path_factory.mktemp("export") / "s.h5")


def _parse_vtk(text: str) -> dict:
    """A minimal reader of our legacy ASCII polydata (independent of the writer's code)."""
    tokens = text.split("\n", 3)
    assert tokens[0].startswith("# vtk DataFile Version") and tokens[2] == "ASCII"
    words = tokens[3].split()
    assert words[:2] == ["DATASET", "POLYDATA"]
    i = 2
    out = {"point": {}, "cell": {}}
    section = None
    while i < len(words):
        w = words[i]
        if w == "POINTS":
            n = int(words[i + 1])
            out["points"] = np.array(words[i + 3:i + 3 + 3 * n], float).reshape(n, 3)
            i += 3 + 3 * n
        elif w == "POLYGONS":
            n, size = int(words[i + 1]), int(words[i + 2])
            poly = np.array(words[i + 3:i + 3 + size], int).reshape(n, 4)
            assert (poly[:, 0] == 3).all()
            out["triangles"] = poly[:, 1:]
            i += 3 + size
        elif w in ("POINT_DATA", "CELL_DATA"):
            section = "point" if w == "POINT_DATA" else "cell"
            out[section + "_n"] = int(words[i + 1])
            i += 2
        elif w == "SCALARS":
            name, n = words[i + 1], out[section + "_n"]
            assert words[i + 4:i + 6] == ["LOOKUP_TABLE", "default"]
            out[section][name] = np.array(words[i + 6:i + 6 + n], float)
            i += 6 + n
        elif w == "VECTORS":
            name, n = words[i + 1], out[section + "_n"]
            out[section][name] = np.array(words[i + 3:i + 3 + 3 * n], float).reshape(n, 3)
            i += 3 + 3 * n
        else:
            raise AssertionError(f"unexpected token {w!r}")
    return out


def test_export_vtk_round_trip(session, tmp_path, capsys):
    assert main(["export", str(session), "-o", str(tmp_path / "vtk")]) == 0
    assert "Exported 7 steps" in capsys.readouterr().out
    with open_session(session) as s:
        fields = compute_fields(s.latest("markers"), s.steps)
    series = json.loads((tmp_path / "vtk" / "surface.vtk.series").read_text())
    assert [f["name"] for f in series["files"]] == [f"surface_{k:03d}.vtk" for k in range(7)]
    for k in (0, 6):
        data = _parse_vtk((tmp_path / "vtk" / f"surface_{k:03d}.vtk").read_text())
        visible = data["point"]["visible"].astype(bool)
        np.testing.assert_allclose(data["points"][visible], fields.positions[k][visible], rtol=0, atol=1e-10)  # %.9g in m
        assert not np.isnan(data["points"]).any()
        tri_index = data["cell"]["triangle"].astype(int)
        np.testing.assert_array_equal(data["triangles"], fields.mesh.triangles[tri_index])
        assert visible[data["triangles"]].all()  # only measured triangles are cells
        np.testing.assert_allclose(data["cell"]["E11"], fields.kin["E11"][k][tri_index], rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(data["cell"]["E22"], fields.kin["E22"][k][tri_index], rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(data["point"]["displacement"][visible],
                                   (fields.positions[k] - fields.positions[0])[visible], atol=1e-10)
    assert abs(np.mean(data["cell"]["E11"]) - 0.345) < 0.02  # 30 % hoop stretch at 150 mmHg in the synthetic tube


def test_export_ply_reads_back_with_trimesh(session, tmp_path):
    assert main(["export", str(session), "-o", str(tmp_path / "ply"), "--format", "ply"]) == 0
    files = sorted((tmp_path / "ply").glob("surface_*.ply"))
    assert len(files) == 7
    mesh = trimesh.load(files[-1], process=False)
    with open_session(session) as s:
        fields = compute_fields(s.latest("markers"), s.steps)
    visible = np.isfinite(fields.positions[-1]).all(axis=1)
    np.testing.assert_allclose(mesh.vertices[visible], fields.positions[-1][visible], atol=1e-9)
    keep = visible[fields.mesh.triangles].all(axis=1)
    np.testing.assert_array_equal(mesh.faces, fields.mesh.triangles[keep])
    assert mesh.visual.face_colors.shape == (keep.sum(), 4)


def test_export_errors(tmp_path, capsys):
    bare = make_session(tmp_path / "bare.h5", with_results=False)
    assert main(["export", str(bare)]) == 2
    assert "no marker tracks yet" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "nope.h5")]) == 2
