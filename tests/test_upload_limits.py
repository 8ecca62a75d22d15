"""An attacker's probes of the upload checks (issue 31): every file shape is a 422 sentence
naming the file — never a 500 — archives are judged by what they expand to within a time
bounded by the bytes read, and models onnxruntime cannot run are refused at the door."""

from __future__ import annotations

import bz2
import gzip
import io
import json
import struct
import tarfile
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from services.lib.archive import MAX_EXPANSION_RATIO, MAX_JSON_DEPTH
from supervisor.artifacts.validation import validate_upload
from supervisor.problems import PROBLEM_MEDIA_TYPE, Problem
from tests.conftest import add_user, auth, make_settings
from tests.plyfiles import mesh_bytes, raw_ply
from tests.sequences import archive_bytes, sequence_members, small_sequence

XYZ = ["property float x", "property float y", "property float z"]
FOUR_POINTS = np.zeros((4, 3), "<f4").tobytes()


def refusal(tmp_path: Path, data: bytes, *, kind: str, name: str = "probe.bin") -> Problem:
    """The Problem validating ``data`` as ``kind`` raises (the test fails if it is kept or
    anything else is raised)."""
    path = tmp_path / "upload"
    path.write_bytes(data)
    with pytest.raises(Problem) as caught:
        validate_upload(path, media_type="application/octet-stream", name=name, kind=kind)
    assert caught.value.status == 422 and name in caught.value.detail, caught.value.detail
    return caught.value


def kept(tmp_path: Path, data: bytes, *, kind: str, name: str = "good.bin") -> dict:
    path = tmp_path / "upload"
    path.write_bytes(data)
    return validate_upload(path, media_type="application/octet-stream", name=name, kind=kind).meta


# --- 1, 2: every PLY header shape and list count is a sentence -------------------------------


@pytest.mark.parametrize(
    ("header", "body", "phrase"),
    [
        (["element vertex 4", "property float x", *XYZ], FOUR_POINTS, "'x' appears twice"),
        (["element vertex 99999999999", *XYZ], FOUR_POINTS, "truncated"),
        (["element vertex " + "9" * 5000, *XYZ], FOUR_POINTS, "5000 digits"),
        (["element vertex 4", "property float128 x", *XYZ[1:]], FOUR_POINTS, "property line"),
        (["element vertex 4", "property list uchar float x"], b"", "must not have list"),
        (["element vertex 4", "property list uchar float x", *XYZ[1:]], b"", "after a list"),
        (["element vertex 4", *XYZ, "property list uchar float n"], b"", "mixes a list"),
        (["element vertex 4", *XYZ, "element vertex 4", *XYZ], FOUR_POINTS, "second element"),
        (["element vertex 4", "comment é", *XYZ], FOUR_POINTS, "non-ASCII"),
        (["comment " + "x" * 70_000, "element vertex 4", *XYZ], FOUR_POINTS, "end_header"),
        (["element vertex four", *XYZ], FOUR_POINTS, "'element NAME COUNT'"),
        (["property float x"], b"", "before any element"),
        (["element vertex 4", *XYZ, "banana"], FOUR_POINTS, "unknown keyword"),
    ],
)
def test_every_ply_header_shape_is_a_sentence(tmp_path, header, body, phrase):
    problem = refusal(tmp_path, raw_ply(header, body), kind="scan", name="cloud.ply")
    assert phrase in problem.detail


def _faces_with_count(count_type: str, count: bytes) -> bytes:
    header = ["element vertex 4", *XYZ, "element face 1"]
    header.append(f"property list {count_type} int vertex_indices")
    return raw_ply(header, FOUR_POINTS + count + np.arange(3, dtype="<i4").tobytes())


@pytest.mark.parametrize("kind", ["scan", "mesh"])
@pytest.mark.parametrize(
    ("count_type", "count", "phrase"),
    [
        ("char", b"\xff", "list of -1 items"),
        ("float", struct.pack("<f", float("nan")), "must be an integer type"),
        ("double", struct.pack("<d", 3.0), "must be an integer type"),
    ],
)
def test_a_list_count_of_minus_one_or_nan_is_refused(tmp_path, kind, count_type, count, phrase):
    data = _faces_with_count(count_type, count)
    assert phrase in refusal(tmp_path, data, kind=kind, name="mesh.ply").detail


def test_a_real_mesh_is_kept_and_a_bad_face_row_is_a_sentence(tmp_path):
    good = mesh_bytes(tmp_path)
    assert kept(tmp_path, good, kind="mesh")["ply"]["faces"] == 24
    last_count = len(good) - 13  # the last triangle's count byte
    bad = good[:last_count] + b"\xff" + good[last_count + 1 :]
    assert "different lengths" in refusal(tmp_path, bad, kind="mesh", name="m.ply").detail


# --- 3: JSON nesting is capped without recursion ---------------------------------------------


def test_json_nested_200000_deep_is_refused_naming_the_limit(tmp_path):
    deep = b"[" * 200_000 + b"]" * 200_000
    problem = refusal(tmp_path, deep, kind="report", name="report.json")
    assert f"{MAX_JSON_DEPTH} levels" in problem.detail


def test_json_depth_counts_brackets_outside_strings_only(tmp_path):
    at_limit = b"[" * MAX_JSON_DEPTH + b"]" * MAX_JSON_DEPTH
    kept(tmp_path, at_limit, kind="report")
    refusal(tmp_path, b"[" + at_limit + b"]", kind="report", name="r.json")
    quoted = json.dumps({"text": "[" * 1000 + '\\"[{' * 300, "n": [[[1]]]}).encode()
    kept(tmp_path, quoted, kind="report")


def test_json_with_an_integer_of_5000_digits_is_a_sentence(tmp_path):
    assert "not valid JSON" in refusal(tmp_path, b"1" * 5000, kind="report", name="r.json").detail


# --- 4: archives are checked for what they expand to ----------------------------------------


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> dict[str, bytes]:
    folder = small_sequence(tmp_path_factory.mktemp("seq") / "seq", seconds=0.05)
    return sequence_members(folder)


def _zip_of_zeros(members: dict[str, bytes], zero_members: dict[str, int]) -> bytes:
    """``members`` stored as they are, plus members of so many zero bytes, deflated
    (about 1000×) without ever holding them whole."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
        for name, size in zero_members.items():
            with archive.open(name, "w", force_zip64=True) as member:
                for _ in range(size >> 24):
                    member.write(bytes(1 << 24))
    return out.getvalue()


def test_a_zip_of_frames_deflated_1000_times_is_refused_by_its_ratio(tmp_path, sequence):
    camera = {name: data for name, data in sequence.items() if name.endswith("camera.json")}
    frames = {f"seq/frames/{k:06d}.png": 16 << 20 for k in range(4)}
    data = _zip_of_zeros(camera, frames)
    assert len(data) < 128 << 10  # 64 MiB of "frames" in 64 KiB
    started = time.process_time()
    problem = refusal(tmp_path, data, kind="frames", name="bomb.zip")
    assert time.process_time() - started < 1.0
    assert "seq/frames/000000.png expands" in problem.detail
    assert f"{MAX_EXPANSION_RATIO}×" in problem.detail


def _tar_of_zeros(compression: str, size: int, first: dict[str, bytes]) -> bytes:
    """A compressed tar of ``first`` then a member of ``size`` zero bytes (a multiple of
    64 MiB): the zeros compressed once and repeated (gzip and bzip2 read concatenated
    streams as one), so a 4 GiB bomb is built in half a second."""
    compress = {"gz": gzip.compress, "bz2": bz2.compress}[compression]
    head = io.BytesIO()
    archive = tarfile.open(fileobj=head, mode="w")  # noqa: SIM115 - never closed: the zeros end it
    for name, data in first.items():
        info = tarfile.TarInfo(name)
        info.size = len(data)
        archive.addfile(info, io.BytesIO(data))
    padding = tarfile.TarInfo("seq/padding.bin")
    padding.size = size
    archive.addfile(padding)  # the header alone
    zeros = compress(bytes(64 << 20))
    return compress(head.getvalue()) + zeros * (size >> 26) + compress(bytes(10240))


@pytest.fixture(scope="module")
def tar_bz2_bomb(sequence) -> bytes:
    """4 GiB of zero padding after a real sequence in a few kilobytes of bzip2: listing it
    took 10.8 s of CPU (and kept it) before the stream was metered."""
    return _tar_of_zeros("bz2", 4 << 30, sequence)


@pytest.mark.parametrize("kind", ["frames", "drive", "lidar"])
def test_a_compressed_tar_stops_expanding_at_its_ratio(tmp_path, tar_bz2_bomb, kind):
    started = time.process_time()
    problem = refusal(tmp_path, tar_bz2_bomb, kind=kind, name="bomb.tar.bz2")
    assert time.process_time() - started < 1.0
    assert "it expands to more than" in problem.detail


def test_a_gzip_bomb_costs_the_bytes_its_ratio_allows_not_all_of_them(tmp_path, sequence):
    data = _tar_of_zeros("gz", 1 << 30, sequence)  # 1 GiB in a MiB
    started = time.process_time()
    problem = refusal(tmp_path, data, kind="frames", name="bomb.tar.gz")
    assert time.process_time() - started < 1.0  # ~200 MiB inflated, not 1 GiB
    assert f"{MAX_EXPANSION_RATIO}×" in problem.detail


def _declaring(data: bytes, suffix: bytes, size: int) -> bytes:
    """A zip whose central directory declares ``size`` bytes for each member whose name
    ends with ``suffix`` (nothing else changed)."""
    patched = bytearray(data)
    end = data.rindex(b"PK\x05\x06")
    entries, _, at = struct.unpack_from("<HII", data, end + 10)
    for _ in range(entries):
        name_bytes, extra_bytes, comment_bytes = struct.unpack_from("<HHH", data, at + 28)
        if data[at + 46 : at + 46 + name_bytes].endswith(suffix):
            struct.pack_into("<I", patched, at + 24, size)
        at += 46 + name_bytes + extra_bytes + comment_bytes
    return bytes(patched)


def test_a_zip_declaring_2_gib_of_frames_is_refused_before_reading(tmp_path, sequence):
    """The attacker's zip: 2 GiB of frames in its directory (kept before: only a 64 GiB
    total was checked, and the frames were never read)."""
    frames = [n for n in sequence if n.endswith(".png")]
    data = _declaring(archive_bytes(sequence, "zip"), b".png", (2 << 30) // len(frames))
    problem = refusal(tmp_path, data, kind="frames", name="bomb.zip")
    assert "expands from" in problem.detail and f"{MAX_EXPANSION_RATIO}×" in problem.detail


@pytest.mark.parametrize("form", ["zip", "tar.gz"])
def test_frames_are_decoded_at_upload_naming_the_one_that_is_not_an_image(tmp_path, sequence, form):
    meta = kept(tmp_path, archive_bytes(sequence, form), kind="frames")
    assert meta["frames"] == len([n for n in sequence if n.endswith(".png")])
    names = sorted(n for n in sequence if n.endswith(".png"))
    broken = dict(sequence)
    broken[names[2]] = sequence[names[2]][: len(sequence[names[2]]) // 2]
    problem = refusal(tmp_path, archive_bytes(broken, form), kind="frames", name="s")
    assert names[2] in problem.detail and "cannot decode" in problem.detail
    import cv2

    small = cv2.imencode(".png", np.zeros((10, 12), np.uint8))[1].tobytes()
    problem = refusal(tmp_path, archive_bytes({**sequence, names[1]: small}, form), kind="frames")
    assert f"{names[1]} is 12 × 10 pixels, but camera.json says 200 × 150" in problem.detail


def test_a_frame_promising_a_gigapixel_is_refused_before_decoding(tmp_path, sequence):
    names = sorted(n for n in sequence if n.endswith(".png"))
    frame = bytearray(sequence[names[0]])
    struct.pack_into(">II", frame, 16, 40_000, 40_000)
    problem = refusal(
        tmp_path, archive_bytes({**sequence, names[0]: bytes(frame)}, "zip"), kind="frames"
    )
    assert "40,000 × 40,000 pixels" in problem.detail


def test_camera_json_nested_deep_inside_a_sequence_is_a_sentence(tmp_path, sequence):
    camera = next(n for n in sequence if n.endswith("camera.json"))
    deep = {**sequence, camera: b"[" * 100_000 + b"]" * 100_000}
    problem = refusal(tmp_path, archive_bytes(deep, "zip"), kind="frames")
    assert "nests arrays or objects" in problem.detail


def test_frame_names_of_thousands_of_digits_sort(tmp_path, sequence):
    frames = sorted(n for n in sequence if n.endswith(".png"))
    renamed = {
        (f"seq/frames/{'9' * (5000 + k)}.png" if name in frames else name): data
        for k, (name, data) in enumerate(sequence.items())
    }
    assert kept(tmp_path, archive_bytes(renamed, "tar"), kind="frames")["frames"] == len(frames)


def test_an_archive_listing_more_files_than_any_sequence_is_refused_unread(tmp_path, monkeypatch):
    import services.lib.archive

    monkeypatch.setattr(services.lib.archive, "MAX_MEMBERS", 50)
    many = {f"seq/{k}.txt": b"" for k in range(60)}
    zipped = refusal(tmp_path, archive_bytes(many, "zip"), kind="frames")
    assert "60 entries" in zipped.detail  # from the zip's end record, before its directory
    tarred = refusal(tmp_path, archive_bytes(many, "tar"), kind="frames")
    assert "more than 50 files" in tarred.detail


# --- 5: models onnxruntime cannot run are refused at the door --------------------------------


def onnx_model_bytes(
    *, op: str = "Relu", domain: str = "", external: bool = False, metadata: object = None
) -> bytes:
    """A two-node model (``input + w`` then ``op``) with vista's metadata: Relu runs; a
    custom domain's op or ``w`` kept in an external file does not."""
    from onnx import TensorProto, helper, numpy_helper

    weight = numpy_helper.from_array(np.ones((1, 4), np.float32), "w")
    if external:
        weight.ClearField("raw_data")
        weight.data_location = TensorProto.EXTERNAL
        location = weight.external_data.add()
        location.key, location.value = "location", "../../etc/passwd"
    graph = helper.make_graph(
        [
            helper.make_node("Add", ["input", "w"], ["sum"]),
            helper.make_node(op, ["sum"], ["output"], domain=domain),
        ],
        "tiny",
        [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 4])],
        [helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, 4])],
        [weight],
    )
    opsets = [helper.make_opsetid("", 17)] + ([helper.make_opsetid(domain, 1)] if domain else [])
    model = helper.make_model(graph, opset_imports=opsets, ir_version=8)
    entry = model.metadata_props.add()
    entry.key = "vista"
    entry.value = json.dumps({"architecture": "tiny"} if metadata is None else metadata)
    return model.SerializeToString()


def test_a_model_onnxruntime_runs_is_kept(tmp_path):
    assert kept(tmp_path, onnx_model_bytes(), kind="model")["architecture"] == "tiny"


@pytest.mark.parametrize(
    ("model", "phrase"),
    [
        (dict(op="Foo", domain="com.example"), "com.example:Foo"),
        (dict(external=True), "external file"),
        (dict(metadata=[1, 2]), "not a JSON object"),
    ],
)
def test_models_onnxruntime_cannot_run_are_refused_at_upload(tmp_path, model, phrase):
    problem = refusal(tmp_path, onnx_model_bytes(**model), kind="model", name="net.onnx")
    assert "not a model vista can run" in problem.detail and phrase in problem.detail


# --- trajectories -------------------------------------------------------------------------


def test_a_trajectory_with_a_zero_quaternion_is_refused_not_kept_as_nan(tmp_path):
    text = b"0 0 0 0 0 0 0 1\n0.1 1 2 0 0 0 0 0\n"
    assert "zero quaternion" in refusal(tmp_path, text, kind="trajectory", name="t.tum").detail


# --- 6: a refusal leaves the connection usable -----------------------------------------------


def _local_port(response: httpx.Response) -> int:
    return response.extensions["network_stream"].get_extra_info("socket").getsockname()[1]


def test_a_refused_upload_leaves_the_keep_alive_connection_working(
    tmp_path, sqlite_url, start_server, sequence
):
    server = start_server(make_settings(tmp_path, sqlite_url), run_engine=False)
    token = add_user(server.app.state.runtime, "ines", "inspector", "ines-pw")
    with httpx.Client(base_url=server.url, headers=auth(token), timeout=30) as http:
        inspection = http.post("/api/v1/inspections", json={"title": "t", "area": "cabin"}).json()[
            "id"
        ]
        url = f"/api/v1/inspections/{inspection}/artifacts"
        not_utf8 = {"seq/frames/0\udcff.png": b"not a png", "seq/frames/1.png": b"", **sequence}
        for kind, body in (
            ("report", b"[" * 200_000 + b"]" * 200_000),
            ("scan", raw_ply(["element vertex 4", "property float x", *XYZ], FOUR_POINTS)),
            ("frames", archive_bytes(not_utf8, "tar")),
        ):
            refused = http.post(
                url,
                params={"kind": kind, "name": "probe"},
                content=body,
                headers={"content-type": "application/octet-stream"},
            )
            assert refused.status_code == 422, refused.text
            assert refused.headers["content-type"] == PROBLEM_MEDIA_TYPE
            listed = http.get(url)
            assert listed.status_code == 200 and listed.json()["items"] == []
            assert _local_port(listed) == _local_port(refused)  # the same connection
