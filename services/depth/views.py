"""What a depth prediction's page shows: per image, the camera image and its depth map (the
colour preview with its scale in metres), a slider between them; the run's figures
(``contract.views``)."""

from __future__ import annotations

from pathlib import Path

from contract.views import Figure, Figures, JobFiles, Picture, Pictures
from services.depth.kinds import PREDICT_REPORT, PREVIEW


def predict_view(files: JobFiles) -> list:
    report = files.json(PREDICT_REPORT.file_name()) or {}
    images = report.get("images", [])
    by_stem = {Path(name).stem: name for name in files.inputs}
    pictures = []
    for image in images:
        stem = image["name"]
        given = by_stem.get(stem)
        layers = ([given] if given else []) + [PREVIEW.file_name(stem)]
        names = (["camera image"] if given else []) + ["depth (m)"]
        pictures.append(Picture(f"{stem} ({image['width']} × {image['height']})", layers, names))
    seconds = [i["seconds"] for i in images]
    figures = [
        Figure("model", report.get("model")),
        Figure("int8", "yes" if report.get("int8") else "no"),
        Figure("images", len(images)),
        Figure(
            "time a frame", round(1000 * sum(seconds) / len(seconds), 1) if seconds else None, "ms"
        ),
        *(Figure(f"{i['name']}: median depth", i["median_depth_m"], "m") for i in images),
        Figure(
            "against ground truth",
            None,
            note="depth.predict has no ground-truth input: `vista depth eval` scores the maps",
        ),
    ]
    return [Pictures("Depth per image", pictures), Figures("Prediction", figures)]
