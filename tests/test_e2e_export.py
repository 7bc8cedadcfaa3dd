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
    assert main(["export", str(session), "-o", str(tmp_path / "vtk"), "--format", "vtk"]) == 0
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


def _pvd(path) -> list[tuple[float, str]]:
    """(time, file) of a ParaView collection, read with the standard library (independent of the writer)."""
    import xml.etree.ElementTree as ET

    root = ET.parse(path).getroot()
    assert root.get("type") == "Collection"
    return [(float(d.get("timestep")), d.get("file")) for d in root.iter("DataSet")]


def test_export_vtu_series_reads_with_meshio(session, tmp_path, capsys):
    """The default export: VTU per step read by meshio; .pvd series with time = pressure per block and clock time;
    fields named by model and component."""
    import meshio

    assert main(["export", str(session), "-o", str(tmp_path / "vtu")]) == 0
    assert "Exported 7 steps" in capsys.readouterr().out
    with open_session(session) as s:
        idents = [s.result(n) for n in s.results("identification")]
        fields = compute_fields(s.latest("markers"), s.steps, idents)
        steps = s.steps
    out = tmp_path / "vtu"
    block = np.asarray(steps["block"])[fields.steps]
    clock = np.asarray(steps["t_monotonic"], float)[fields.steps]
    for b in (0, 1):
        series = _pvd(out / f"surface_block{b}.pvd")
        rows = np.flatnonzero(block == b)
        assert [f for _, f in series] == [f"surface_{k:03d}.vtu" for k in rows]
        np.testing.assert_array_equal([t for t, _ in series], fields.pressure[rows])  # time = pressure in Pa
    clock_series = _pvd(out / "surface_clock.pvd")
    assert [f for _, f in clock_series] == [f"surface_{k:03d}.vtu" for k in range(7)]
    np.testing.assert_allclose([t for t, _ in clock_series], clock - clock[0])
    models = sorted({str(r["attrs"]["model"]) for r in idents})
    assert len(models) >= 2
    for k in (0, 6):
        mesh = meshio.read(out / f"surface_{k:03d}.vtu")
        assert [c.type for c in mesh.cells] == ["triangle"]
        names = set(mesh.cell_data)
        assert {"E_theta", "E_z", "E_theta_z", "area_m2", "triangle"} <= names
        for model in models:
            assert {f"{model}_sigma_theta_Pa", f"{model}_sigma_z_Pa"} <= names
        tri_index = mesh.cell_data["triangle"][0].astype(int)
        np.testing.assert_array_equal(mesh.cells[0].data, fields.mesh.triangles[tri_index])
        np.testing.assert_array_equal(mesh.cell_data["E_theta"][0], fields.kin["E11"][k][tri_index])
        np.testing.assert_array_equal(mesh.cell_data["E_z"][0], fields.kin["E22"][k][tri_index])
        stress = next(st for st in fields.stress.values() if st["model"] == models[0])
        np.testing.assert_array_equal(mesh.cell_data[f"{models[0]}_sigma_theta_Pa"][0], stress["s11"][k][tri_index])
        visible = mesh.point_data["visible"].astype(bool)
        np.testing.assert_array_equal(mesh.points[visible], fields.positions[k][visible])
        assert mesh.point_data["displacement_m"].shape == (len(mesh.points), 3)
        used = np.unique(mesh.cells[0].data)
        np.testing.assert_allclose(np.linalg.norm(mesh.point_data["normal"][used], axis=1), 1.0, atol=1e-9)
        assert np.isnan(np.delete(mesh.point_data["normal"], used, axis=0)).all()  # in no cell: no normal
        assert np.all(mesh.cell_data["area_m2"][0] > 0)
        np.testing.assert_allclose(float(mesh.field_data["pressure_Pa"][0]), fields.pressure[k])
        np.testing.assert_allclose(float(mesh.field_data["clock_s"][0]), clock[k] - clock[0])
        assert int(mesh.field_data["step"][0]) == k
