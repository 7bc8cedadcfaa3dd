"""A real session writer process for the crash test: writes steps until killed."""

import sys
import time

import numpy as np

from acquisition.session import CameraSpec, SessionWriter, SpecimenInfo, StepRecord

path, ready = sys.argv[1], sys.argv[2]
spec = SpecimenInfo("crash", 10e-3, 35e-3, 1.3e-3)
writer = SessionWriter.create(path, spec, cameras=[CameraSpec("cam0", "sim", 320, 240)], protocol_text="x = 1\n")
rng = np.random.default_rng(0)
step = 0
while True:
    t = time.monotonic()
    writer.append_log("pressure", [t], [time.time()], [step * 100.0], [f" {step}"], seq=[step])
    image = rng.integers(0, 255, (240, 320), dtype=np.uint8)
    writer.add_step(StepRecord(0, 1.1, step * 100.0, step * 100.0 + 1, 0.5, t, time.time()), {"cam0": image})
    with open(ready, "a") as fh:  # tell the test which steps are complete
        fh.write(f"{step}\n")
    step += 1
