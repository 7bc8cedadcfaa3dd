"""The operator at a real terminal: ``vfmlab run --sim`` (manual pressure) driven through a pseudo-terminal.

The operator confirms the start, presses Enter at each "set the pressure" prompt, hits Ctrl-C and chooses
"quit": the live view, the prompts (live view suspended) and the pause menu all run on a real tty.
"""

import os
import pty
import re
import select
import signal
import subprocess
import sys
import time

from acquisition.session import open_session
from test_run_session_sim import FAST, ROOT, SPECIMEN

ANSI = re.compile(rb"\x1b\[[0-9;?]*[a-zA-Z]")


class Terminal:
    def __init__(self, argv, cwd):
        self.master, slave = pty.openpty()
        env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", COLUMNS="100", LINES="30",
                   TERM="xterm")
        self.proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, env=env, cwd=cwd)
        os.close(slave)
        self.raw = b""

    def pump(self, seconds=0.05):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ready, _, _ = select.select([self.master], [], [], 0.02)
            if ready:
                try:
                    self.raw += os.read(self.master, 65536)
                except OSError:
                    return

    @property
    def text(self):
        return ANSI.sub(b"", self.raw).decode("utf-8", "replace")

    def expect(self, pattern, timeout=30, answer_enter=False):
        """Wait for ``pattern`` (whitespace-normalised text); optionally press Enter at every new
        "press Enter" prompt meanwhile (the operator keeps setting pressures)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.pump()
            if answer_enter:
                self.answer_enter_prompts()
            if re.search(pattern, re.sub(r"\s+", " ", self.text)):
                return
        raise AssertionError(f"no {pattern!r} on the terminal:\n{self.text[-3000:]}")

    answered = 0

    def answer_enter_prompts(self):
        n = self.text.count("press Enter")
        for _ in range(n - self.answered):
            self.send(b"\n")
        self.answered = max(self.answered, n)

    def send(self, data):
        os.write(self.master, data)

    def wait_exit(self, timeout):
        """Wait for the process to end while reading its output, as a terminal does: a process
        writing more than the pty buffer holds (e.g. the live view's last frame with live results)
        blocks until it is read."""
        end = time.monotonic() + timeout
        while self.proc.poll() is None and time.monotonic() < end:
            self.pump(0.1)
        return self.proc.wait(max(end - time.monotonic(), 0.1))

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        os.close(self.master)


def _steps(path):
    try:
        with open_session(path) as s:
            return s.n_steps
    except Exception:  # noqa: BLE001 - not created yet
        return -1


def test_operator_session_on_a_real_terminal(tmp_path):
    rig = tmp_path / "manual-rig.toml"
    rig.write_text((ROOT / "examples" / "sim-rig.toml").read_text().replace('mode = "controller"', 'mode = "manual"')
                   .replace("width = 640, height = 480", "width = 320, height = 240"))
    proto = tmp_path / "p.toml"
    proto.write_text(FAST.replace("stretches = [1.1, 1.2]", "stretches = [1.1]")
                     .replace("pressure_cycles = 8", "pressure_cycles = 1")
                     .replace("stretch_cycles = 8", "stretch_cycles = 1"))
    out = tmp_path / "t.h5"
    term = Terminal([sys.executable, "-m", "vfmlab", "run", str(proto), "--specimen", str(SPECIMEN),
                     "--out", str(out), "--rig", str(rig), "--sim", "--sim-speed", "5", "--no-detect"], cwd=tmp_path)
    try:
        term.expect(r"Start the test\? Nothing has moved yet\.\s+Choose \(start, cancel\)")
        term.send(b"start\n")
        term.expect(r"Do 1 pressure cycles 0 -> 80 mmHg")  # manual rig: preconditioning by hand
        t0 = time.monotonic()
        while _steps(out) < 2:
            assert time.monotonic() - t0 < 40, term.text[-3000:]
            term.pump(0.05)
            term.answer_enter_prompts()
        assert "Set the pressure to 20.0 mmHg (2.67 kPa), then press Enter" in term.text
        term.proc.send_signal(signal.SIGINT)
        term.expect(r"Paused\. Resume, retake the last step, add a note, quit \(resume later\) or abort\?",
                    answer_enter=True)
        term.send(b"note\n")
        term.expect(r"Note for the session record")
        term.send(b"clamp slipped a little\n")
        term.expect(r"add a note.*add a note", timeout=10)
        term.send(b"quit\n")
        term.wait_exit(30)
        term.pump(0.3)
        assert term.proc.returncode == 0, term.text[-3000:]
        text = term.text
        assert "Pressure" in text and "mmHg" in text and "kPa" in text and "Force" in text and "Protocol" in text
        assert "Session interrupted" in text and "Continue with: vfmlab resume" in text
    finally:
        term.close()
    with open_session(out) as s:
        assert s.status == "interrupted" and s.n_steps >= 2
        assert s.instruments["pressure"]["identity"].startswith("MENSOR, CPG2500")  # an indicator: manual rig
        assert any(e["kind"] == "note" and e["message"] == "clamp slipped a little" for e in s.events())
