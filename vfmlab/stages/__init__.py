"""The stages under the command line, one function each, taking a frozen settings object whose defaults are the
command line's (:mod:`vfmlab.stages.settings`); ``vfmlab/__init__.py`` re-exports them as the Python front door.

=================  ==========================================  ==============================
stage              function                                    command
=================  ==========================================  ==============================
calibrate          :func:`vfmlab.stages.calibrate.calibrate`    ``vfmlab calibrate``
reconstruct        :func:`vfmlab.stages.reconstruct.reconstruct` ``vfmlab reconstruct``
identify           :func:`vfmlab.stages.identify.identify`      ``vfmlab identify``
regional           :func:`vfmlab.stages.identify.regional`      ``vfmlab identify --regions``
report, export     :mod:`vfmlab.stages.outputs`                 ``vfmlab report``, ``vfmlab export``
loads export       :func:`vfmlab.stages.loads.export_loads`     ``vfmlab export-loads``
run, reprocess     :mod:`vfmlab.stages.batch`                   ``vfmlab run``, ``vfmlab reprocess``
check-rig          :func:`vfmlab.stages.check.check_rig`        ``vfmlab check-rig``
=================  ==========================================  ==============================

A stage never prints: it raises :class:`~vfmlab.stages.errors.StageError` (bad input, exit code 2) or
:class:`~vfmlab.stages.errors.StageFailed` (exit code 1), and reports notes and progress through callbacks
(:mod:`vfmlab.stages.feedback`). The numerical work stays in :mod:`vfmlab.pipeline`, :mod:`vfmlab.regional`,
:mod:`vfmlab.operate`, :mod:`vfmlab.reprocess` and the stage packages; nothing here is imported eagerly.
"""
