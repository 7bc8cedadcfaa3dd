"""Run one vfmlab command in this process, SIGKILLed at its N-th write of the session (a patched writer).

``python kill_at_write_child.py N COUNT_FILE ARGS...``: N = 0 runs to the end and writes the number of writes
to COUNT_FILE. The writes counted are every HDF5 dataset write of the session writer (``_writer._put``: step
rows, frames, logs, events) and every file creation and rename (``os.replace``, ``os.rename``), which is
where ``run``, ``resume`` and ``import-markers`` put bytes on the disk.
"""

import os
import signal
import sys

from acquisition.session import _writer

N, COUNT_FILE = int(sys.argv[1]), sys.argv[2]
seen = [0]


def _counted(real):
    def wrapper(*args, **kwargs):
        seen[0] += 1
        if seen[0] == N:
            os.kill(os.getpid(), signal.SIGKILL)
        return real(*args, **kwargs)
    return wrapper


_writer._put = _counted(_writer._put)
os.replace = _counted(os.replace)
os.rename = _counted(os.rename)

from vfmlab.cli import main  # noqa: E402 - after the patches

rc = main(sys.argv[3:])
with open(COUNT_FILE, "w") as fh:
    fh.write(str(seen[0]))
sys.exit(rc)
