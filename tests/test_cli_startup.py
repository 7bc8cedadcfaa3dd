"""``vfmlab.cli._startup.modules_loading``: the collector paused while a command loads its modules, the
loaded objects frozen for the command, and an in-process caller left with the collector it had."""

import gc

import pytest

from vfmlab.cli import _startup
from vfmlab.cli._startup import modules_loading


@pytest.fixture(autouse=True)
def _in_process(monkeypatch):
    monkeypatch.setattr(_startup, "_process_ends", False)  # as when the tests call vfmlab.cli.main([...])
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_paused_while_loading_frozen_while_working_restored_after():
    with modules_loading() as loaded:
        assert not gc.isenabled()
        loaded_objects = len(gc.get_objects())
        loaded()
        assert gc.isenabled()
        assert gc.get_freeze_count() >= loaded_objects * 0.9  # what existed is out of the collections
        loaded()  # a second call changes nothing
        assert gc.isenabled()
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_an_import_error_leaves_the_collector_as_it_was():
    with pytest.raises(ImportError):
        with modules_loading() as loaded:
            import vfmlab_no_such_module  # noqa: F401
            loaded()
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_a_caller_with_its_own_collector_settings_keeps_them():
    gc.disable()
    try:
        with modules_loading() as loaded:
            loaded()
            assert not gc.isenabled()  # it was off: it stays off
        assert not gc.isenabled()
    finally:
        gc.enable()
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with modules_loading() as loaded:
            loaded()
        assert gc.get_freeze_count() >= 0.9 * frozen  # the caller's freeze is left alone (not unfrozen)
    finally:
        gc.unfreeze()


def test_a_process_that_ends_after_the_command_keeps_the_modules_frozen(monkeypatch):
    monkeypatch.setattr(_startup, "_process_ends", True)
    try:
        with modules_loading() as loaded:
            loaded()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
