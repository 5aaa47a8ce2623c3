"""The shared TU Delft Prius detections for the benchmark scripts (``../shared`` beside the
checkout)."""

from __future__ import annotations

from pathlib import Path

from rigcal.dataset import Dataset
from rigcal.io.dataset.manifest import dataset_from_files

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "tudelft_prius" / "detections"


def prius_dataset() -> Dataset | None:
    """lidar1, camera1, radar1 of the 29 Prius boards; None (after saying why) when absent."""
    if not DATA.is_dir():
        print(f"benchmark data not found at {DATA} (needs ../shared beside the checkout)")
        return None
    return dataset_from_files(
        lidar=[DATA / "lidar.csv"], camera=[DATA / "camera.csv"], radar=[DATA / "radar.csv"]
    )
