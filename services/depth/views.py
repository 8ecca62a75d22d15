"""What a depth prediction's page shows: per image, the camera image, its depth map (the
colour preview with its scale in metres) and its error against ground truth when given, a
slider between them; the seven metrics; the run's figures
(``contract.views``); and its 3D scene, each image's cloud (``contract.scene``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contract.scene import JobScene, PointSet
from contract.views import ColourScale, Figure, Figures, JobFiles, Picture, Pictures
from services.depth.kinds import CLOUD, ERROR_MAP, PREDICT_REPORT, PREVIEW

SEVEN = (
    ("abs_rel", "AbsRel", ""),
    ("sq_rel", "SqRel", "m"),
    ("rmse", "RMSE", "m"),
    ("rmse_log", "RMSE log", ""),
    ("delta1", "δ < 1.25", ""),
    ("delta2", "δ < 1.25²", ""),
    ("delta3", "δ < 1.25³", ""),
)
"""The depth literature's seven metrics as the page names them."""


ERROR_SCALE = ColourScale(["#00ff00", "#ffff00", "#ff0000"], "0 %", "≥ 50 %")
"""The error map's colours (``predict.error_map``): green at 0 through yellow to red at 50 %."""


def predict_view(files: JobFiles) -> list:
    report = files.json(PREDICT_REPORT.file_name()) or {}
    images = report.get("images", [])
    by_stem = {Path(name).stem: f"image/{name}" for name in files.inputs_of_kind("image")}
    pictures = []
    for image in images:
        stem = image["name"]
        given = by_stem.get(stem)
        layers = ([given] if given else []) + [PREVIEW.file_name(stem)]
        names = (["camera image"] if given else []) + ["depth (m)"]
        scales: list[ColourScale | None] = [None] * len(layers)  # the preview has its own bar
        if ERROR_MAP.file_name(stem) in files.outputs:
            layers.append(ERROR_MAP.file_name(stem))
            names.append("error against ground truth (relative to the true depth)")
            scales.append(ERROR_SCALE)
        label = f"{stem} ({image['width']} × {image['height']})"
        pictures.append(Picture(label, layers, names, layer_scales=scales))
    seconds = [i["seconds"] for i in images]
    figures = [
        Figure("model", report.get("model")),
        Figure("int8", "yes" if report.get("int8") else "no"),
        Figure("images", len(images)),
        Figure(
            "time a frame", round(1000 * sum(seconds) / len(seconds), 1) if seconds else None, "ms"
        ),
        *(Figure(f"{i['name']}: median depth", i["median_depth_m"], "m") for i in images),
    ]
    evaluation = report.get("evaluation")
    if evaluation is None:
        why = "no ground-truth `depth` maps were given (named as the images)"
        figures.append(Figure("against ground truth", None, note=why))
    else:
        figures.append(
            Figure("images scored", evaluation["images"], note="median-scaled, Garg crop")
        )
        figures += [
            Figure(name, evaluation.get(key), unit, note="no image could be scored")
            for key, name, unit in SEVEN
        ]
        figures += [
            Figure(
                f"{i['name']}: AbsRel",
                i["evaluation"].get("abs_rel"),
                note=i["evaluation"].get("unmeasured", ""),
            )
            for i in images
            if "evaluation" in i
        ]
    return [Pictures("Depth per image", pictures), Figures("Prediction", figures)]


def predict_scene(files: JobFiles, max_points: int) -> JobScene:
    """Each image's cloud as coloured points (the point budget shared among them), turned
    from the camera's frame (x right, y down, z forward) to +Z up (x forward, y left)."""
    from services.lib.pointcloud.ply import read_ply_sample

    report = files.json(PREDICT_REPORT.file_name()) or {}
    images = [i["name"] for i in report.get("images", [])]
    clouds = [(stem, files.outputs.get(CLOUD.file_name(stem))) for stem in images]
    clouds = [(stem, path) for stem, path in clouds if path is not None]
    if not clouds:
        raise ValueError("the prediction wrote no clouds (it ran with clouds off)")
    budget = max(1, max_points // len(clouds))
    points = []
    for stem, path in clouds:
        cloud = read_ply_sample(path, budget)
        x, y, z = cloud.points.T
        points.append(
            PointSet(
                f"cloud-{stem}", np.column_stack([z, -x, -y]), cloud.colors, extras={"image": stem}
            )
        )
    return JobScene(
        points=tuple(points),
        frame="the camera's (x forward, y left, z up)",
        extras={
            "figures": {k: v for k, v in files.result.items() if not isinstance(v, dict)},
            "legend": [
                {
                    "gradient": ["#303030", "#a0a0a0", "#ffffff"],
                    "text": "points: each image's own colours at their predicted depth, in "
                    "its camera's frame (one image at a time)",
                }
            ],
        },
    )
