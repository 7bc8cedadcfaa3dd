"""The real data sets kept in the repository (tests/data/<set>/, each with its SOURCE.md): the one way tests reach
them. A missing file is an error naming the path, never a skip; nothing outside the repository is read."""

from pathlib import Path

#: tests/data of this checkout
DATA_DIR = Path(__file__).resolve().parent / "data"


def data_path(name: str) -> Path:
    """``tests/data/<name>`` (a set, e.g. ``"openptv-test-cavity"``, or a file in one); FileNotFoundError naming the
    path when it is not there (the data are part of the repository: a missing file is a broken checkout)."""
    path = DATA_DIR / name
    if not path.exists():
        raise FileNotFoundError(f"test data {name!r}: expected {path}, not found (tests/data is part of the "
                                f"repository; see tests/data/README.md)")
    return path
