"""House habits the README's test command enforces: ``ruff check`` and ``mypy`` pass on the product packages,
with the settings of pyproject.toml ([tool.ruff], [tool.mypy]). Both come with the ``test`` extra; without one
the test is skipped with the reason, but in CI (``CI`` set, as .ci/run does) it fails instead."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ["acquisition", "reconstruction", "identification", "rig_sim", "vfmlab"]


def _tool(module: str) -> None:
    """Skip (or fail in CI) when ``module`` is not installed."""
    if importlib.util.find_spec(module) is None:
        why = f"needs {module} (in the 'test' extra: pip install -e '.[test]')"
        if os.environ.get("CI"):
            pytest.fail(f"{why} (CI is set: CI machines must have it)")
        pytest.skip(why)


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def test_ruff_passes_on_the_product_packages():
    _tool("ruff")
    done = _run(["ruff", "check", "--no-cache", *PRODUCT], timeout=120)
    assert done.returncode == 0, f"ruff check failed:\n{done.stdout}\n{done.stderr}"


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_mypy_passes_on_the_product_packages():
    _tool("mypy")
    # The packages come from [tool.mypy] in pyproject.toml; its cache (.mypy_cache/, git-ignored) makes reruns fast.
    done = _run(["mypy"], timeout=880)
    assert done.returncode == 0, f"mypy failed:\n{done.stdout}\n{done.stderr}"
