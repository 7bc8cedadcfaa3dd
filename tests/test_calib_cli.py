"""``vfmlab calibrate`` from an image folder and from a session."""

import json

import cv2
import numpy as np
import pytest

from rig_sim.calibration_scene import rendered_charuco
from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, open_session
from reconstruction.calibration_io import cameras_from_arrays, cameras_from_toml, cameras_from_yaml
from vfmlab.cli import main


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    cams, views, _ = rendered_charuco()
    root = tmp_path_factory.mktemp("boards")
    for c in cams:
        (root / c.name).mkdir()
        for k, img in enumerate(views.images[c.name][:12]):
            cv2.imwrite(str(root / c.name / f"view{k:02d}.png"), img)
    return cams, views, root


def test_calibrate_folder_to_toml(folder, tmp_path, capsys):
    cams, views, root = folder
    out = tmp_path / "calibration.toml"
    rc = main(["calibrate", "--images", str(root), "--fix-k3", "-o", str(out), "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    summary = json.loads(captured.out)
    assert summary["converged"] and summary["rms_total_px"] < 0.1
    assert [r["camera"] for r in summary["cameras"]] == [c.name for c in cams]
    back, meta = cameras_from_toml(out.read_text())
    assert meta["units"] == "mm" and len(back) == 4
    for a, b in zip(back, cams):
        np.testing.assert_allclose(a.K[0, 0], b.K[0, 0], rtol=3e-3)
    # the relative pose of two cameras is metric: baseline to 0.1 %
    base_est = np.linalg.norm(back[1].center - back[0].center)
    base_true = np.linalg.norm(cams[1].center - cams[0].center)
    assert abs(base_est / base_true - 1) < 1e-3


def test_calibrate_session_stores_result(tmp_path, capsys):
    cams, views, _ = rendered_charuco()
    path = tmp_path / "s.h5"
    specs = [CameraSpec(c.name, "sim", c.image_size[0], c.image_size[1]) for c in cams]
    with SessionWriter.create(path, SpecimenInfo("t", 0.01, 0.035, 0.001), cameras=specs) as w:
        for k in range(12):
            w.add_calibration_view({c.name: views.images[c.name][k] for c in cams})
    out = tmp_path / "calibration.yaml"
    rc = main(["calibrate", str(path), "--fix-k3", "-o", str(out), "--units", "m"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "stored as calibration_001" in captured.out and "converged: True" in captured.out
    assert "cam3" in captured.out and "Calibration" in captured.out
    back, meta = cameras_from_yaml(out.read_text())
    assert meta["units"] == "m" and len(back) == 4
    with open_session(path) as s:
        res = s.latest("calibration")
    est = cameras_from_arrays(res["arrays"])
    assert [c.name for c in est] == [c.name for c in cams]
    assert res["arrays"]["rms"].shape == (4,) and np.all(res["arrays"]["rms"] < 0.1)
    assert res["units"]["tvec"] == "m" and res["parameters"]["board"] == "charuco"


def test_calibrate_errors(tmp_path, capsys):
    assert main(["calibrate"]) == 2
    assert "SESSION" in capsys.readouterr().err
    assert main(["calibrate", "--images", str(tmp_path)]) == 2
    assert "camera sub-folders" in capsys.readouterr().err
    assert main(["calibrate", "--images", str(tmp_path), "--squares", "8by6"]) == 2
    assert "--squares" in capsys.readouterr().err
    (tmp_path / "camA").mkdir()
    assert main(["calibrate", "--images", str(tmp_path), "-o", str(tmp_path / "c.json")]) == 2
    assert ".toml" in capsys.readouterr().err


def test_import_aniposelib_into_session_and_convert(tmp_path, capsys):
    from rig_sim.cameras import camera_ring
    from reconstruction.calibration_io import cameras_to_toml

    cams = camera_ring(3, image_size=(640, 480))
    toml_text = cameras_to_toml(cams).replace('units = "mm"\n', "")  # as aniposelib writes it: no unit
    src = tmp_path / "calibration.toml"
    src.write_text(toml_text)
    path = tmp_path / "s.h5"
    with SessionWriter.create(path, SpecimenInfo("t", 0.01, 0.035, 0.001),
                              cameras=[CameraSpec(c.name, "sim", 640, 480) for c in cams[::-1]]):
        pass
    out = tmp_path / "converted.yaml"
    rc = main(["calibrate", str(path), "--import", str(src), "-o", str(out), "--units", "m", "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert json.loads(captured.out)["stored_as"] == "calibration_001"
    with open_session(path) as s:
        stored = cameras_from_arrays(s.latest("calibration")["arrays"])
        order = s.camera_names
    assert [c.name for c in stored] == order  # session order
    by_name = {c.name: c for c in stored}
    np.testing.assert_allclose(by_name["cam0"].tvec, cams[0].tvec, atol=1e-15)  # mm in the file -> m
    back, meta = cameras_from_yaml(out.read_text())
    np.testing.assert_allclose(back[1].tvec, cams[1].tvec, atol=1e-15)
    # wrong unit option changes the scale; a session camera missing from the file is refused
    rc = main(["calibrate", str(path), "--import", str(src), "--import-units", "m", "--json"])
    assert rc == 0
    with open_session(path) as s:
        again = {c.name: c for c in cameras_from_arrays(s.latest("calibration")["arrays"])}
    np.testing.assert_allclose(again["cam0"].tvec, cams[0].tvec * 1e3)
    capsys.readouterr()
    path2 = tmp_path / "s2.h5"
    with SessionWriter.create(path2, SpecimenInfo("t", 0.01, 0.035, 0.001), cameras=[CameraSpec("other", "sim", 640, 480)]):
        pass
    assert main(["calibrate", str(path2), "--import", str(src)]) == 2
    assert "'other'" in capsys.readouterr().err
