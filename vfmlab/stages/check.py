"""The check-rig stage: open the rig (or the simulated one), run the pre-flight check of :mod:`vfmlab.preflight`,
keep the images with their detections in a folder."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vfmlab.preflight import RigCheck

__all__ = ["check_rig"]

log = logging.getLogger(__name__)


def check_rig(settings: Any = None, *, notify: Callable[[str], None] | None = None, **overrides: Any) -> RigCheck:
    """``vfmlab check-rig``: open the rig (``sim``: the simulated one), check it, save the images if ``out``."""
    import contextlib
    from importlib import resources

    from acquisition.cameras import CameraError
    from acquisition.protocol import ConfigError, parse_protocol, parse_specimen
    from vfmlab.bench import BenchError, open_bench
    from vfmlab.operate import OperateError, load_rig_config
    from vfmlab.preflight import check_bench, rig_calibration, save_check
    from vfmlab.stages.errors import StageError, StageFailed
    from vfmlab.stages.settings import CheckRigSettings, settings_with

    s = settings_with(CheckRigSettings, settings, overrides)
    if s.sim_seed is not None and not s.sim:
        raise StageError(f"--sim-seed sets the simulated rig's seed and needs --sim; got --sim-seed {s.sim_seed}")
    try:
        rig = load_rig_config(s.rig, s.sim, s.sim_seed)
    except ConfigError as exc:
        raise StageError(str(exc)) from None
    except OperateError as exc:
        raise (StageError if exc.exit_code == 2 or not s.rig else StageFailed)(str(exc)) from None
    with contextlib.ExitStack() as stack:
        simbench = None
        if s.sim:
            from vfmlab.simrig import SimBench

            data = resources.files("vfmlab.data")
            protocol = parse_protocol(data.joinpath("demo-protocol.toml").read_text(encoding="utf-8"), rig=rig)
            specimen = parse_specimen(data.joinpath("demo-specimen.toml").read_text(encoding="utf-8"))
            simbench = stack.enter_context(SimBench(rig, specimen, protocol))
        try:
            bench = stack.enter_context(open_bench(rig, simbench))
            check = check_bench(bench, seconds=s.seconds, limits=s.limits, calibration=rig_calibration(rig, bench))
        except (BenchError, CameraError) as exc:
            raise StageFailed(str(exc)) from None
    if s.out:
        try:
            written = save_check(check, s.out)
        except OSError as exc:
            raise StageFailed(f"--out {s.out}: {exc}") from None
        (notify or log.info)(f"images with their detections and check.json written to {Path(s.out)} "
                             f"({len(written)} files)")
    return check
