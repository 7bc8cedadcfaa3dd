"""Which identification steps are captures of the stress-free reference (``[reference] repeats``, issue 24).

A session run from a protocol with ``[reference] capture = true`` images the reference as block 0 (``repeats``
times, each a step of the session); the identification averages those steps into one reference
(``identification.identify(..., reference_repeats=N)``). The decision comes from what the session records: its
protocol (stored as text) and the block of each step row. A session without that information (imported markers,
an empty or unreadable protocol, a protocol without a captured reference) is identified as before: no averaging.
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["averaged_inputs", "reference_repeats"]

log = logging.getLogger(__name__)


def reference_repeats(protocol_text: str, blocks: np.ndarray) -> int:
    """Leading identification steps that are captures of the reference (1 = no averaging).

    Parameters
    ----------
    protocol_text : str
        The protocol the session was run with (``Session.protocol_text``; "" for imported sessions).
    blocks : ndarray of int, shape (n_steps,)
        The protocol block of each step the identification uses, in order (``steps["block"][rows]``).

    Returns
    -------
    int
        The number of leading steps of block 0 when the protocol captured the reference (block 0 is the
        reference, ``Protocol.has_reference``) and at least one loaded step follows; else 1.
    """
    from acquisition.protocol import ConfigError, parse_protocol

    blocks = np.asarray(blocks).reshape(-1)
    if not protocol_text.strip() or blocks.size < 3:
        return 1
    try:
        protocol = parse_protocol(protocol_text, source="<session protocol>")
    except ConfigError as exc:
        log.info("the session's protocol does not parse (%s): the reference captures are not averaged", exc)
        return 1
    if not protocol.has_reference:
        return 1
    not_reference = np.flatnonzero(blocks != 0)
    n = int(not_reference[0]) if not_reference.size else int(blocks.size)
    return n if 1 < n < blocks.size else 1


def averaged_inputs(data: dict) -> dict:
    """The identification inputs of ``vfmlab.pipeline.load_identification_inputs`` with the reference captures
    averaged into one step (``identification.reference_repeats``), for the identifications that take arrays
    without ``reference_repeats`` (regional): positions, pressure, force, rows and uncertainty shortened alike;
    ``data`` itself when there is one capture."""
    from identification.reference_repeats import average_reference, averaged_marker_sigma, kept_steps

    n = int(data.get("reference_repeats", 1))
    if n <= 1:
        return data
    keep = kept_steps(len(data["rows"]), n)
    out = dict(data, positions=average_reference(data["positions"], n)[0], pressure=np.asarray(data["pressure"])[keep],
               force=np.asarray(data["force"])[keep], rows=np.asarray(data["rows"])[keep], reference_repeats=1)
    if data.get("uncertainty") is not None:
        out["uncertainty"] = averaged_marker_sigma(data["uncertainty"], n)
    return out
