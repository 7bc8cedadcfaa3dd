"""The Python front door (``import vfmlab``): the code of docs/guide/python-api.md runs, and the library's
defaults are the command line's (same settings, bit-identical stored parameters)."""

import dataclasses
import re
from pathlib import Path

import click
import numpy as np
import pytest

import vfmlab
from acquisition.session import copy_session, open_session
from vfmlab.cli import cli, main

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "guide" / "python-api.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)


@pytest.fixture(scope="module")
def doc_dir(tmp_path_factory):
    """The doc's code blocks run in order in one namespace, in a fresh folder (they make tube.h5 there)."""
    folder = tmp_path_factory.mktemp("python_api")
    cwd = Path.cwd()
    namespace: dict = {}
    try:
        import os

        os.chdir(folder)
        for i, block in enumerate(_blocks()):
            exec(compile(block, f"{DOC.name} block {i + 1}", "exec"), namespace)
    finally:
        os.chdir(cwd)
    return folder, namespace


def test_the_doc_has_code_and_it_runs(doc_dir):
    folder, ns = doc_dir
    assert len(_blocks()) >= 4
    assert (folder / "tube.h5").exists() and ns["out"].result.converged


def test_the_front_door_lists_its_names_and_imports_them_on_first_use():
    for name in ("open_session", "identify", "reconstruct", "calibrate", "report", "export", "reprocess",
                 "IdentifySettings", "ReconstructSettings", "CalibrateSettings", "ReportSettings", "ExportSettings",
                 "ReprocessSettings"):
        assert name in vfmlab.__all__ and name in dir(vfmlab)
        assert getattr(vfmlab, name) is not None
    import importlib

    for module in ("vfmlab.export", "vfmlab.reprocess", "vfmlab.report"):  # the submodules keep their paths ...
        importlib.import_module(module)
    from vfmlab.report import build_report  # noqa: F401

    assert callable(vfmlab.export) and callable(vfmlab.report) and callable(vfmlab.reprocess)  # ... not the names
    assert vfmlab.open_session is open_session


_COMMANDS = {"identify": vfmlab.IdentifySettings, "reconstruct": vfmlab.ReconstructSettings,
             "calibrate": vfmlab.CalibrateSettings, "report": vfmlab.ReportSettings,
             "export": vfmlab.ExportSettings, "reprocess": vfmlab.ReprocessSettings, "run": vfmlab.RunSettings}


@pytest.mark.parametrize("command", list(_COMMANDS))
def test_settings_defaults_are_the_command_line_defaults(command):
    params = {p.name: p for p in cli.get_command(click.Context(cli), command).params if isinstance(p, click.Option)}
    settings = _COMMANDS[command]()
    compared = 0
    for f in dataclasses.fields(settings):
        option = params.get(f.name)
        if option is None:
            continue
        default = option.default if type(option.default).__name__ != "Sentinel" else None
        if option.is_flag and default is None and not option.secondary_opts:  # a flag without a default is off
            default = False  # (an --on/--off pair without a default passes None: neither given)
        if option.multiple and default is None:
            default = ()
        value = getattr(settings, f.name)
        assert value == default, (command, f.name, value, default)
        compared += 1
    assert compared >= 2, command


def test_library_and_command_store_the_same_parameters(doc_dir, tmp_path):
    folder, _ = doc_dir
    by_command, by_library = tmp_path / "a.h5", tmp_path / "b.h5"
    with open_session(folder / "tube.h5") as s:  # the session as the doc made it, before any identification
        assert s.results("markers")
    for copy in (by_command, by_library):
        copy_session(folder / "tube.h5", copy)  # the file and its derived results
    assert main(["identify", str(by_command), "--model", "fung"]) == 0
    out = vfmlab.identify(by_library, model="fung")
    with open_session(by_command) as a, open_session(by_library) as b:
        ra, rb = a.latest("identification"), b.latest("identification")
    assert out.group == rb["name"]
    for key in ("parameters", "stderr", "parameter_names", "correlation", "ivw", "evw"):
        x, y = np.asarray(ra["arrays"][key]), np.asarray(rb["arrays"][key])
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), key
    assert ra["parameters"] == rb["parameters"]  # the settings stored with the result
    assert ra["attrs"]["invoked_by"] == "identify" and rb["attrs"]["invoked_by"] == "python"
