"""Where the real camera images live: ``$LIVETRACK_REALDATA`` or ``../shared/realdata`` beside the repository."""

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def realdata_dir() -> Path | None:
    folder = Path(os.environ.get("LIVETRACK_REALDATA", REPO.parent / "shared" / "realdata"))
    return folder if folder.is_dir() else None
