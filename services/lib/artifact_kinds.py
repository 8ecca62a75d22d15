"""The kinds of file every service may write or read: clouds, reports, figures, models,
scenes, camera images, anything else. A service declares the kinds only it knows in its own
``kinds`` module; the supervisor's registry collects both."""

from contract.artifacts import ArtifactKind

FORMATS = "services.lib.formats"

ARTIFACT_KINDS = (
    ArtifactKind(
        "cloud",
        "A point cloud (PLY, mm): stitched scans in the robot's base frame, or a depth map's "
        "points in its camera's frame.",
        f"{FORMATS}:inspect_cloud",
    ),
    ArtifactKind("report", "A job's or a tool's report.", f"{FORMATS}:inspect_json"),
    ArtifactKind("plot", "A figure.", f"{FORMATS}:inspect_png"),
    ArtifactKind("scene", "A 3D scene for viewers (binary glTF).", f"{FORMATS}:inspect_glb"),
    ArtifactKind(
        "model",
        "A learned model: ONNX with vista's metadata (its training command).",
        f"{FORMATS}:inspect_model",
    ),
    ArtifactKind("image", "A camera image (PNG or JPEG).", f"{FORMATS}:inspect_image"),
    ArtifactKind(
        "other", "Any file kept with the inspection; no job reads it.", f"{FORMATS}:inspect_any"
    ),
)
