"""What a tracking run's page shows: the confidence over the frames with the detector's runs
and the resets marked, the box's path seen from above, and the run's figures
(``contract.views``)."""

from __future__ import annotations

from contract.views import Figure, Figures, JobFiles, Line, Plot
from services.tracking.kinds import EVALUATION, TRACK_REPORT


def track_view(files: JobFiles) -> list:
    document = files.json(TRACK_REPORT.file_name()) or {}
    frames = document.get("frames", [])
    index = [float(f["frame"]) for f in frames]
    confidence = [float(f["confidence"]) for f in frames]
    lines = [Line("confidence", index, confidence)]
    for what, key in (("detector ran", "detector_ran"), ("reset", "reset")):
        marked = [k for k, f in enumerate(frames) if f.get(key)]
        if marked:
            lines.append(
                Line(
                    what,
                    [index[k] for k in marked],
                    [confidence[k] for k in marked],
                    style="points",
                )
            )
    x = [float(f["lidar_box"]["x"]) for f in frames]
    y = [float(f["lidar_box"]["y"]) for f in frames]
    panels: list = [
        Plot("Confidence over the drive", "frame", "confidence", lines),
        Plot(
            "The box's path from above (LiDAR frame)",
            "x (m)",
            "y (m)",
            [Line("box centre", x, y)],
            equal_axes=True,
        ),
    ]
    figures = [
        Figure("frames", len(frames)),
        Figure("detector runs", document.get("detector_runs")),
        Figure("detector cost", document.get("detector_cost_percent"), "% of frames"),
        Figure("speed", document.get("fps"), "frames/s"),
        Figure("resets", sum(1 for f in frames if f.get("reset"))),
    ]
    evaluation = files.json(EVALUATION.file_name())
    if evaluation is None:
        figures.append(Figure("success / precision", None, note="the drive had no labels"))
    else:
        figures += [
            Figure(key.replace("_", " "), value)
            for key, value in evaluation.items()
            if isinstance(value, int | float | str) and not isinstance(value, bool)
        ]
    return panels + [Figures("Run", figures)]
